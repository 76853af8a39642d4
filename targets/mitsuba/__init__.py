"""Light transport as a target: Mitsuba 3 scenes in primary sample space.

`PrimarySampleSpace` turns a scene into the density `p(u) = luminance(f(u))` on
`[0, 1)^D`, where `f(u)` is the contribution of the camera path that Mitsuba's `path`
integrator would trace from the random numbers `u`. It offers batch evaluation with
gradients (NumPy), a `jax.pure_callback` bridge usable under `jit`/`vmap`, and the plain
uniform Monte Carlo image. `MultiplexedBDPT` is the same for multiplexed bidirectional
path tracing (depth and strategy chosen by the first coordinate). `_native` renders with Mitsuba's own integrator for equal-time
baselines and cached references; `_scenes` builds the test scenes in code.

Importing this package does not import Mitsuba: it is loaded (with a working libLLVM,
see `load_mitsuba`) on first use. Install it with `pip install 'restore-mcmc[mitsuba]'`.
"""

from ._bdpt_target import MultiplexedBDPT as MultiplexedBDPT
from ._llvm import LLVMNotFoundError as LLVMNotFoundError
from ._llvm import find_libllvm as find_libllvm
from ._llvm import load_mitsuba as load_mitsuba
from ._native import (
    NativeRender as NativeRender,
)
from ._native import (
    native_paths_per_second as native_paths_per_second,
)
from ._native import (
    read_exr as read_exr,
)
from ._native import (
    reference_image as reference_image,
)
from ._native import (
    render_native as render_native,
)
from ._native import (
    render_native_for as render_native_for,
)
from ._native import (
    write_exr as write_exr,
)
from ._path_tracer import dimension as dimension
from ._path_tracer import trace_paths as trace_paths
from ._scene_checks import UnsupportedSceneError as UnsupportedSceneError
from ._scenes import (
    SCENES as SCENES,
)
from ._scenes import (
    caustic as caustic,
)
from ._scenes import (
    cornell_box as cornell_box,
)
from ._scenes import (
    door_ajar as door_ajar,
)
from ._scenes import (
    door_gap as door_gap,
)
from ._scenes import (
    glass_torus as glass_torus,
)
from ._scenes import (
    load_scene as load_scene,
)
from ._scenes import (
    pool as pool,
)
from ._scenes import (
    scene_dict as scene_dict,
)
from ._target import PathSamples as PathSamples
from ._target import PrimarySampleSpace as PrimarySampleSpace
