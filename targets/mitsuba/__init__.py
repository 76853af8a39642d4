"""Light transport as a target: Mitsuba 3 scenes in primary sample space.

`PrimarySampleSpace` turns a scene into the density `p(u) = luminance(f(u))` on
`[0, 1)^D`, where `f(u)` is the contribution of the camera path that Mitsuba's `path`
integrator would trace from the random numbers `u`. It offers batch evaluation with
gradients (NumPy), a `jax.pure_callback` bridge usable under `jit`/`vmap`, and the plain
uniform Monte Carlo image. `_native` renders with Mitsuba's own integrator for equal-time
baselines and cached references; `_scenes` builds the test scenes in code.

Importing this package does not import Mitsuba: it is loaded (with a working libLLVM,
see `load_mitsuba`) on first use. Install it with `pip install 'restore-mcmc[mitsuba]'`.
"""

from ._llvm import LLVMNotFoundError as LLVMNotFoundError, find_libllvm as find_libllvm, load_mitsuba as load_mitsuba
from ._native import (
    NativeRender as NativeRender,
    native_paths_per_second as native_paths_per_second,
    read_exr as read_exr,
    reference_image as reference_image,
    render_native as render_native,
    render_native_for as render_native_for,
    write_exr as write_exr,
)
from ._path_tracer import dimension as dimension, trace_paths as trace_paths
from ._scene_checks import UnsupportedSceneError as UnsupportedSceneError
from ._scenes import (
    SCENES as SCENES,
    caustic as caustic,
    cornell_box as cornell_box,
    door_ajar as door_ajar,
    glass_torus as glass_torus,
    load_scene as load_scene,
    scene_dict as scene_dict,
)
from ._target import PathSamples as PathSamples, PrimarySampleSpace as PrimarySampleSpace
