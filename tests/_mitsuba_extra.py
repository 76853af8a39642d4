"""Whether the `mitsuba` extra is installed, found without importing Mitsuba or Dr.Jit.

Importing Dr.Jit before `targets.mitsuba.load_mitsuba` has chosen its libLLVM would pin
the wrong one, so the Mitsuba test modules check with `find_spec` only.
"""

import importlib.util

import pytest


def mitsuba_extra_installed() -> bool:
    try:
        return all(importlib.util.find_spec(name) is not None for name in ("mitsuba", "drjit"))
    except (ImportError, ValueError):
        return False


def xml_scene(width: int, height: int, max_depth: int, rfilter: str = "gaussian", integrator: str = "path") -> str:
    """A small Mitsuba XML scene: a diffuse sphere lit by an area light, seen by a pinhole camera."""
    return f"""<scene version="3.0.0">
  <integrator type="{integrator}"><integer name="max_depth" value="{max_depth}"/></integrator>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/>
      <rfilter type="{rfilter}"/></film>
  </sensor>
  <shape type="sphere"><bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>
"""


def mitsuba_or_skip():
    """Mitsuba with its CPU variant, or a skip whose reason says that libLLVM is missing."""
    from targets.mitsuba import LLVMNotFoundError, load_mitsuba

    try:
        return load_mitsuba("llvm_ad_rgb")
    except LLVMNotFoundError as err:
        pytest.skip(f"Mitsuba is installed but its CPU variant cannot run: libLLVM is missing. {err}")
