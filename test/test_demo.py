"""`make demo` in a reduced form: a small scene through the node process over DDS."""

from pathlib import Path

from geomodel_ros.tools.demo import run_demo


def test_reduced_demo_models_every_frame_and_writes_pictures(tmp_path, capsys):
    code = run_demo(tmp_path / "demo", scenes=("tiny_box",), frames=2, rate=4.0)
    out = capsys.readouterr().out
    assert code == 0, out
    assert "2/2 frames modeled" in out
    assert "2/2 objects found with the right type" in out
    for name in ("segments.png", "reconstruction.png", "overlay.png"):
        png = Path(tmp_path / "demo" / "tiny_box" / name)
        assert png.exists() and png.stat().st_size > 10_000
