"""Property-based tests of the light-transport layer's input handling: scene files and images.

Unreadable or malformed scene files (missing, a directory, no permission, random bytes,
truncated XML, XML that is not a scene, scenes with unsupported or broken elements) given
to `targets.mitsuba.load_scene`, `PrimarySampleSpace` and `restore render` give a clear
error naming the file, never a crash of Dr.Jit; an interrupted EXR write leaves the old
file (or none) and no temporary file.

Mitsuba loads are slow, so examples are few (derandomized, no deadline); every scene is
loaded at 4x4 pixels and depth 2. Skipped without the `mitsuba` extra.
"""

from __future__ import annotations

import errno
import os
import random
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from tests._mitsuba_extra import mitsuba_extra_installed, mitsuba_or_skip

if not mitsuba_extra_installed():
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

from typer.testing import CliRunner  # noqa: E402

from restore.cli import app  # noqa: E402
from targets.mitsuba import PrimarySampleSpace, UnsupportedSceneError, load_scene  # noqa: E402

SCENES = settings(derandomize=True, database=None, deadline=None, max_examples=15,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
FEW = settings(SCENES, max_examples=6)

SCENE = b"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <shape type="sphere"><bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>
"""


@pytest.fixture(scope="module")
def mi():
    return mitsuba_or_skip()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("scenes")


def write_scene(folder: Path, content: bytes, name: str = "scene.xml") -> Path:
    path = folder / name
    path.write_bytes(content)
    return path


def load_outcome(path: Path):
    """Load `path` as the PSS target: `(target, None)`, or `(None, error)` for a clear error."""
    try:
        scene = load_scene(path, resolution=(4, 4), max_depth=2)
    except ValueError as error:
        assert path.name in str(error), error  # the file is named
        return None, error
    try:
        return PrimarySampleSpace(scene), None
    except (UnsupportedSceneError, ValueError) as error:
        return None, error


def assert_target_works(target: PrimarySampleSpace) -> None:
    samples = target.evaluate(np.full((4, target.dim), 0.5))
    assert np.all(np.isfinite(samples.luminance)) and np.all(samples.luminance >= 0)


def assert_no_temporary_files(folder: Path) -> None:
    assert not [p.name for p in folder.iterdir() if p.name.startswith(".")]


def render_cli(scene: Path, out: Path):
    return CliRunner().invoke(app, ["render", str(scene), "--time", "1", "--out", str(out), "--resolution", "4",
                                    "--max-depth", "2", "--lanes", "64", "--no-progress"])


# --------------------------------------------------------------------------- malformed files


@SCENES
@given(content=st.one_of(st.binary(max_size=200), st.binary(max_size=100).map(lambda b: b"<scene version='3.0.0'>" + b)))
@example(content=b"")
@example(content=b"\xff\xfe<\x00s\x00")  # a UTF-16 byte-order mark
@example(content=b"<?xml version='1.0' encoding='no-such-codec'?><scene version='3.0.0'/>")
def test_random_bytes_are_refused_clearly(mi, folder, content):
    path = write_scene(folder, content, "random.xml")
    target, error = load_outcome(path)
    assert target is None and isinstance(error, ValueError), error
    assert_no_temporary_files(folder)


@SCENES
@given(cut=st.integers(0, len(SCENE) - 1))
def test_truncated_scenes_are_refused_clearly(mi, folder, cut):
    path = write_scene(folder, SCENE[:cut], "truncated.xml")
    target, error = load_outcome(path)
    if SCENE[:cut].rstrip() == SCENE.rstrip():  # only whitespace was cut: still the whole scene
        assert error is None, error
        assert_target_works(target)
    else:
        assert isinstance(error, ValueError) and "XML parsing failed" in str(error), error
    assert_no_temporary_files(folder)


PLUGINS = {
    "shape": ["sphere", "rectangle", "cube", "obj", "no_such_shape"],
    "bsdf": ["diffuse", "conductor", "dielectric", "no_such_bsdf"],
    "emitter": ["area", "point", "constant", "envmap", "no_such_emitter"],
    "sensor": ["perspective", "thinlens", "orthographic", "radiancemeter", "no_such_sensor"],
    "integrator": ["path", "volpath", "direct", "no_such_integrator"],
    "film": ["hdrfilm", "specfilm", "no_such_film"],
}
PROPERTIES = {
    "float": ["1", "0", "-1", "nan", "inf", "1e40", "abc", ""],
    "integer": ["1", "0", "-1", "4294967296", "1.5", "x"],
    "rgb": ["1", "0.5, 0.5, 0.5", "-1", "nan", "1, 2"],
    "string": ["x", "", "missing.obj"],
    "boolean": ["true", "false", "maybe"],
}
NAMES = ["radius", "fov", "width", "height", "max_depth", "radiance", "reflectance", "filename", "value", "intensity"]


@st.composite
def elements(draw, depth: int = 0):
    """A random Mitsuba-like element: a plugin with properties and children, or a property,
    or an element Mitsuba does not know."""
    kind = draw(st.sampled_from(sorted(PLUGINS) + sorted(PROPERTIES) + ["bogus", "include", "default", "ref"]))
    element = ElementTree.Element(kind)
    if kind in PLUGINS:
        element.set("type", draw(st.sampled_from(PLUGINS[kind])))
        if depth < 2:
            for child in draw(st.lists(elements(depth + 1), max_size=3)):
                element.append(child)
    elif kind in PROPERTIES:
        element.set("name", draw(st.sampled_from(NAMES)))
        element.set("value", draw(st.sampled_from(PROPERTIES[kind])))
    elif kind in ("include", "ref"):
        element.set("filename" if kind == "include" else "id", draw(st.sampled_from(["missing.xml", "", "scene.xml"])))
    elif kind == "default":
        element.set("name", "spp")
        element.set("value", draw(st.sampled_from(["4", "$x"])))
    return element


@st.composite
def xml_documents(draw):
    """Valid XML: a random tree under a random root, or the good scene with one random
    mutation (an element removed, replaced or added, an attribute changed)."""
    if draw(st.booleans()):
        root = ElementTree.Element(draw(st.sampled_from(["scene", "scene", "shape", "foo", "integrator"])))
        version = draw(st.sampled_from([None, "3.0.0", "2.1.0", "99.0.0", "x"]))
        if version is not None:
            root.set("version", version)
        for child in draw(st.lists(elements(), max_size=4)):
            root.append(child)
        return ElementTree.tostring(root)
    root = ElementTree.fromstring(SCENE)
    everything = list(root.iter())[1:]
    parents = {child: parent for parent in root.iter() for child in parent}
    target = everything[draw(st.integers(0, len(everything) - 1))]
    action = draw(st.sampled_from(["remove", "replace", "add", "attribute"]))
    if action == "remove":
        parents[target].remove(target)
    elif action == "replace":
        parent = parents[target]
        index = list(parent).index(target)
        parent.remove(target)
        parent.insert(index, draw(elements(1)))
    elif action == "add":
        target.append(draw(elements(1)))
    else:
        attribute = draw(st.sampled_from(["type", "value", "name", "version"]))
        target.set(attribute, draw(st.sampled_from(["", "nan", "-1", "no_such_thing", "0", "1e40"])))
    return ElementTree.tostring(root)


@SCENES
@given(document=xml_documents())
@example(document=b"<foo/>")  # valid XML, not a scene
@example(document=b"<shape type='sphere'/>")  # a Mitsuba object, not a scene
@example(document=SCENE.replace(b'<bsdf type="diffuse"/>', b'<bsdf type="no_such_bsdf"/>'))
@example(document=SCENE.replace(b"<sensor", b"<bogus/><sensor"))  # an element Mitsuba does not support
@example(document=SCENE.replace(b'type="perspective">', b'type="perspective"><float name="fov" value="nan"/>'))
def test_xml_that_is_not_a_usable_scene_is_refused_clearly(mi, folder, document):
    """Either a target that evaluates to finite, non-negative values, or a clear error: a
    `ValueError` naming the file, or `UnsupportedSceneError` saying what is unsupported."""
    path = write_scene(folder, document, "mutated.xml")
    target, error = load_outcome(path)
    if error is None:
        assert_target_works(target)
    else:
        assert isinstance(error, ValueError), error
        assert "temporary" not in str(error) and ".mutated-" not in str(error), error  # names the user's file
    assert_no_temporary_files(folder)


# --------------------------------------------------------------------------- unreadable files


@pytest.mark.parametrize("kind", ["missing", "directory", "no permission", "folder not writable"])
def test_unreadable_scene_files_are_refused_clearly(mi, tmp_path, monkeypatch, kind):
    path = tmp_path / "scene.xml"
    if kind == "directory":
        path.mkdir()
    elif kind != "missing":
        path.write_bytes(SCENE)
    if kind == "no permission":
        def denied(source, *args, **kwargs):
            raise PermissionError(errno.EACCES, "Permission denied", str(source))

        monkeypatch.setattr(ElementTree, "parse", denied)  # root can read anything: simulate
    if kind == "folder not writable":
        import tempfile

        def read_only(*args, **kwargs):
            raise PermissionError(errno.EACCES, "Permission denied")

        monkeypatch.setattr(tempfile, "mkstemp", read_only)
    expected = {"missing": (FileNotFoundError, "not found"), "directory": (ValueError, "is a directory"),
                "no permission": (ValueError, "Permission denied"), "folder not writable": (ValueError, "not writable")}[kind]
    with pytest.raises(expected[0], match=expected[1]) as info:
        load_scene(path)
    assert "scene.xml" in str(info.value)
    with pytest.raises(expected[0], match=expected[1]):
        PrimarySampleSpace(path)
    result = render_cli(path, tmp_path / "out.exr")
    assert result.exit_code == 2 and "scene.xml" in result.output and expected[1] in result.output, result.output
    assert not (tmp_path / "out.exr").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their permissions")
def test_a_scene_without_read_permission_is_refused_clearly(mi, tmp_path):
    path = write_scene(tmp_path, SCENE)
    path.chmod(0)
    try:
        with pytest.raises(ValueError, match="cannot read the scene file.*scene.xml"):
            load_scene(path)
    finally:
        path.chmod(0o644)


# --------------------------------------------------------------------------- the command line


@FEW
@given(kind=st.sampled_from(["bytes", "truncated", "not a scene", "unsupported element"]), seed=st.integers(0, 1000))
def test_restore_render_refuses_malformed_scenes_clearly(mi, tmp_path_factory, kind, seed):
    folder = tmp_path_factory.mktemp("cli")
    rng = random.Random(seed)
    content = {
        "bytes": bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 120))),
        "truncated": SCENE[: rng.randint(0, len(SCENE) - 20)],
        "not a scene": rng.choice([b"<foo/>", b"<shape type='sphere'/>", b"<html><body/></html>"]),
        "unsupported element": SCENE.replace(b"<sensor", rng.choice([b"<bogus/><sensor", b"<shape type='nope'/><sensor"])),
    }[kind]
    scene = write_scene(folder, content, "bad.xml")
    out = folder / "image.exr"
    result = render_cli(scene, out)
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert "bad.xml" in result.output and "error" in result.output, result.output
    assert isinstance(result.exception, SystemExit)  # a clean exit, not an exception from Mitsuba
    assert not out.exists() and sorted(p.name for p in folder.iterdir()) == ["bad.xml"]


# --------------------------------------------------------------------------- interrupted EXR writes


@FEW
@given(old=st.one_of(st.none(), st.binary(max_size=32)), fraction=st.floats(0.0, 1.0),
       failure=st.sampled_from(["disk full", "Ctrl-C"]), via=st.sampled_from(["save_image", "write_exr"]))
def test_interrupted_exr_writes_leave_the_old_file_or_none(mi, tmp_path_factory, monkeypatch, old, fraction, failure, via):
    from restore.render._images import save_image
    from targets.mitsuba import write_exr

    folder = tmp_path_factory.mktemp("exr")
    path = folder / "image.exr"
    if old is not None:
        path.write_bytes(old)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}

    def broken_write_bitmap(filename, image, write_async=True):
        data = b"v/1\x01" + bytes(200)  # the start of an EXR file
        Path(filename).write_bytes(data[: int(fraction * len(data))])
        raise OSError(errno.ENOSPC, "No space left on device") if failure == "disk full" else KeyboardInterrupt()

    image = np.ones((2, 3, 3), np.float32)
    with monkeypatch.context() as patch:
        patch.setattr(mi.util, "write_bitmap", broken_write_bitmap)
        with pytest.raises((OSError, KeyboardInterrupt)):
            (save_image if via == "save_image" else write_exr)(path, image)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_exr_writes_are_complete_and_keep_the_usual_permissions(mi, tmp_path):
    from restore.render._images import load_image, save_image

    image = np.linspace(0, 3, 4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    previous = os.umask(0o022)
    try:
        path = save_image(tmp_path / "image.exr", image)
    finally:
        os.umask(previous)
    np.testing.assert_allclose(load_image(path), image)
    assert path.stat().st_mode & 0o777 == 0o644  # not the temporary file's private 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["image.exr"]
