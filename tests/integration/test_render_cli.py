"""`restore render` and `restore render-compare` on tiny Mitsuba scenes, and their error messages."""

import numpy as np
import pytest
from typer.testing import CliRunner

from restore.cli import app
from tests._mitsuba_extra import mitsuba_extra_installed, xml_scene

if not mitsuba_extra_installed():
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

POINT_LIGHT_XML = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <emitter type="point"><point name="position" x="0" y="2" z="2"/><rgb name="intensity" value="10"/></emitter>
  <shape type="rectangle"><bsdf type="diffuse"/></shape>
</scene>
"""


def _invoke(*args):
    return CliRunner().invoke(app, list(map(str, args)))


def test_render_writes_the_image_and_a_preview(tmp_path):
    from restore.render._images import load_image

    out = tmp_path / "cornell.exr"
    result = _invoke("render", "cornell_box", "--method", "restore", "--evaluations", 200_000, "--resolution", 8,
                     "--max-depth", 2, "--lanes", 512, "--no-progress", "--out", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "restore on cornell_box" in result.output
    rows = dict(line.strip("│ ").split(" │ ", 1) for line in result.output.splitlines() if line.count("│") == 3)
    rows = {label.strip(): value.strip() for label, value in rows.items() if label.strip()}
    # the budget takes whole steps of 512 paths, and finishing the open tours adds more
    assert int(rows["paths"].replace(",", "")) > 200_000 - 512 and rows["paths/s"].endswith("(budget and finishing)")
    assert [part.split(" s ")[1] for part in rows["time"].split(", ")] == ["scene", "compile", "budget", "finishing"]
    assert float(rows["tours"].split()[0].replace(",", "")) > 0 and rows["k_hat"].split()[0].replace(".", "").isdigit()
    assert rows["reliable"].split(":")[0] in ("yes", "no")
    image = load_image(out)
    assert image.shape == (8, 8, 3) and np.all(np.isfinite(image)) and image.sum() > 0
    assert out.with_suffix(".png").stat().st_size > 100


def test_the_help_and_the_error_name_the_same_scenes():
    from targets.mitsuba import SCENES

    help_text = _invoke("render", "--help").output
    refused = _invoke("render", "no_such_scene", "--time", 1)
    assert refused.exit_code == 2 and "unknown scene name" in refused.output, refused.output
    listed = lambda text: [name for name in sorted(SCENES) if name in text]  # noqa: E731
    assert listed(help_text) == listed(refused.output) == sorted(SCENES)
    assert "finishing" in help_text and "compiling" in help_text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("render", "no/such/scene.xml", "--time", 1), "not found"),
        (("render", "cornell_box", "--method", "bogus", "--time", 1), "unknown method"),
        (("render", "cornell_box"), "give a budget"),
        (("render", "cornell_box", "--time", 1, "--out", "image.jpg"), "must end in .exr or .npy"),
        (("render", "cornell_box", "--time", 1, "--resolution", "8x"), "--resolution"),
    ],
)
def test_render_reports_bad_input_clearly(args, message):
    result = _invoke(*args)
    assert result.exit_code == 2 and message in result.output, result.output


def test_render_rejects_a_malformed_scene_and_delta_lights_for_gradients(tmp_path):
    broken = tmp_path / "broken.xml"
    broken.write_text("<scene version='3.0.0'><shape type='sphere'>")
    result = _invoke("render", broken, "--time", 1, "--out", tmp_path / "x.exr")
    assert result.exit_code == 2 and "broken.xml" in result.output, result.output

    point = tmp_path / "point.xml"
    point.write_text(POINT_LIGHT_XML)
    result = _invoke("render", point, "--method", "mala-restore", "--time", 1, "--out", tmp_path / "x.exr")
    assert result.exit_code == 2 and "point" in result.output.lower(), result.output


@pytest.fixture
def traced_depths(monkeypatch):
    """The maximum depths of the primary-sample-space targets `restore render` builds."""
    import targets.mitsuba

    depths = []

    class Spy(targets.mitsuba.PrimarySampleSpace):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            depths.append(self.max_depth)

    monkeypatch.setattr(targets.mitsuba, "PrimarySampleSpace", Spy)
    return depths


def test_an_xml_scene_keeps_its_own_size_and_depth_and_changes_are_printed(tmp_path, traced_depths):
    from restore.render._images import load_image

    scene, out = tmp_path / "mine.xml", tmp_path / "mine.npy"
    scene.write_text(xml_scene(12, 10, 3))
    common = ("--method", "uniform", "--evaluations", 2000, "--lanes", 64, "--no-progress", "--out", out)
    result = _invoke("render", scene, *common)
    assert result.exit_code == 0, result.output
    assert load_image(out).shape == (10, 12, 3) and traced_depths == [3]
    assert "gaussian reconstruction filter is replaced by a box filter" in result.output
    assert "replaces the scene's" not in result.output

    result = _invoke("render", scene, "--resolution", "8x6", "--max-depth", 2, *common)
    assert result.exit_code == 0, result.output
    assert load_image(out).shape == (6, 8, 3) and traced_depths[-1] == 2
    assert "film size 8x6 replaces the scene's 12x10" in result.output
    assert "maximum path depth 2 replaces the scene's 3" in result.output


def test_render_refuses_a_volumetric_integrator(tmp_path):
    scene = tmp_path / "fog.xml"
    scene.write_text(xml_scene(12, 10, 3, integrator="volpath"))
    for method in ("uniform", "path"):
        result = _invoke("render", scene, "--method", method, "--evaluations", 1000, "--out", tmp_path / "x.npy")
        assert result.exit_code == 2 and "`volpath` integrator" in result.output, result.output


def test_render_compare_writes_the_table_figures_and_ratios(tmp_path, monkeypatch):
    monkeypatch.setenv("RESTORE_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "results"
    result = _invoke("render-compare", "--scenes", "cornell_box", "--methods", "path,pssmlt,restore", "--time", 0.3,
                     "--realisations", 2, "--resolution", 8, "--max-depth", 2, "--lanes", 256, "--reference-spp", 64,
                     "--no-progress", "--out", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    text = (out / "results.md").read_text()
    assert "Metropolis Restore / pssmlt" in text and "Metropolis Restore / path" in text and "PSS paths/s" in text
    assert (out / "scene-cornell_box.png").stat().st_size > 10_000
    rows = (out / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 3 * 2
    header = rows[0].split(",")
    restore_rows = [dict(zip(header, row.split(","))) for row in rows[1:] if ",restore," in row]
    assert len(restore_rows) == 2 and all(float(row["tours_completed"]) > 0 for row in restore_rows)
    assert all(float(row["effective_tours"]) <= float(row["tours_completed"]) for row in restore_rows)
    assert "Metropolis Restore's tours, per realisation" in text and "effective tours" in text


def test_render_compare_on_multiplexed_bdpt(tmp_path, monkeypatch):
    """`--technique bdpt`: Restore and MMLT on MultiplexedBDPT beside Mitsuba's path tracer;
    MALA Restore is skipped with the reason (no gradients). Restore runs its own lane count."""
    monkeypatch.setenv("RESTORE_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "results"
    result = _invoke("render-compare", "--scenes", "cornell_box", "--methods", "path,pssmlt,restore,mala-restore",
                     "--technique", "bdpt", "--time", 0.3, "--realisations", 1, "--resolution", 8, "--max-depth", 2,
                     "--lanes", "256,restore=512", "--reference-spp", 64, "--no-progress", "--out", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    text = (out / "results.md").read_text()
    assert "Metropolis Restore / MMLT" in text and "multiplexed BDPT" in text
    assert "pssmlt lanes 256, restore lanes 512" in text
    assert "skipped: needs gradients" in text
    assert len((out / "results.csv").read_text().splitlines()) == 1 + 3
    refused = _invoke("render-compare", "--technique", "vcm", "--out", out)
    assert refused.exit_code == 2 and "unknown technique 'vcm'" in refused.output, refused.output


@pytest.mark.parametrize(
    ("lanes", "message"),
    [
        ("256,restore=0", "positive integers"),
        ("path=256", "not a PSS method"),
        ("restore:256", "--lanes must look like"),
    ],
)
def test_render_compare_refuses_bad_lane_counts_before_rendering(tmp_path, lanes, message):
    result = _invoke("render-compare", "--scenes", "cornell_box", "--lanes", lanes, "--out", tmp_path)
    assert result.exit_code == 2 and message in result.output, result.output
    assert not any(tmp_path.iterdir())


def test_each_method_keeps_its_own_default_lanes_unless_told():
    from restore.render._compare import lanes_by_method
    from restore.render._methods import LANES, METHOD_LANES

    methods = ("path", "pssmlt", "restore")
    restore_lanes = METHOD_LANES["restore"]
    assert restore_lanes != LANES
    assert lanes_by_method(None, methods) == {"pssmlt": LANES, "restore": restore_lanes}
    assert lanes_by_method({"pssmlt": 512}, methods) == {"pssmlt": 512, "restore": restore_lanes}
    assert lanes_by_method({"*": 1024}, methods) == lanes_by_method(1024, methods) == {"pssmlt": 1024, "restore": 1024}
    assert lanes_by_method({"*": 1024, "restore": 64}, methods) == {"pssmlt": 1024, "restore": 64}


def test_render_checkpoint_resumes_to_the_same_image(tmp_path):
    from restore._checkpoint import read_header
    from restore.render._images import load_image

    args = ("render", "cornell_box", "--method", "restore", "--evaluations", 100_000, "--resolution", 8,
            "--max-depth", 2, "--lanes", 256, "--no-progress", "--checkpoint", tmp_path / "run.ckpt")  # fmt: skip
    first = _invoke(*args, "--out", tmp_path / "first.npy")
    assert first.exit_code == 0, first.output
    assert read_header(tmp_path / "run.ckpt")["lanes"] == 256
    again = _invoke(*args, "--out", tmp_path / "again.npy")  # resumed from the finished checkpoint
    assert again.exit_code == 0, again.output
    np.testing.assert_array_equal(load_image(tmp_path / "again.npy"), load_image(tmp_path / "first.npy"))
    refused = _invoke(*args[:-2], "--checkpoint", tmp_path / "run.ckpt", "--seed", 1, "--out", tmp_path / "x.npy")
    assert refused.exit_code == 2 and "belongs to another run" in refused.output, refused.output
    path = _invoke("render", "cornell_box", "--method", "path", "--time", 1, "--checkpoint", tmp_path / "p.ckpt")
    assert path.exit_code == 2 and "--checkpoint works with the PSS methods" in path.output


def test_native_render_keeps_the_finished_passes_on_ctrl_c():
    from targets.mitsuba import load_scene, render_native_for

    calls = []

    def interrupt_on_the_second_pass(image, elapsed):
        calls.append(image)
        if len(calls) == 2:
            raise KeyboardInterrupt

    scene = load_scene("cornell_box", (8, 8), 2)
    native = render_native_for(scene, 60.0, pass_paths=128, on_update=interrupt_on_the_second_pass)
    assert native.interrupted and native.spp == 4 and native.seconds < 60.0
    np.testing.assert_array_equal(native.image, calls[1])
