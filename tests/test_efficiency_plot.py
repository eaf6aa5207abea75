"""`sphgraph plot efficiency`: E against N from an efficiency JSON (curve or measured),
with the seed paper's points; PNG and SVG; a clear error on a file without results."""
import json
import subprocess
import sys

import pytest

from sphgraph.errors import InputError
from sphgraph.plots import efficiency_series, plot_efficiency

CURVE = {"scene": "examples/yeh_petroff.toml", "particles": 16_000_000,
         "variants": {"cpu": {"label": "CPU ranks", "schedules": {
             "production": {"1": {"E": 1.0}, "2": {"E": 0.97}, "4": {"E": 0.9}},
             "bulk-synchronous": {"1": {"E": 1.0}, "2": {"E": 0.95}, "4": {"E": 0.85}}}}}}
MEASURED = {"scene": "dambreak2d", "ranks": 2, "E": 0.6, "predicted": {"E": 0.7}}


def test_series_from_both_formats():
    s = efficiency_series(CURVE)
    assert [x["N"] for x in s] == [[1, 2, 4], [1, 2, 4]]
    assert s[1]["E"] == [1.0, 0.95, 0.85] and s[1]["schedule"] == "bulk-synchronous"
    m = efficiency_series(MEASURED)
    assert m[0]["measured"] and m[0]["E"] == [1.0, 0.6] and m[1]["E"] == [1.0, 0.7]


def test_plot_png_svg_and_outdir(tmp_path):
    pytest.importorskip("matplotlib")
    f = tmp_path / "efficiency.json"
    f.write_text(json.dumps(CURVE))
    png = plot_efficiency(f)
    assert png.endswith("efficiency.png") and (tmp_path / "efficiency.png").stat().st_size > 1000
    svg = plot_efficiency(tmp_path, path=tmp_path / "e.svg")          # a directory holding efficiency.json
    text = open(svg).read()
    assert "<svg" in text and "0.81" in text                           # the paper's 14-GPU point is labelled
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(InputError):
        plot_efficiency(bad)


def test_cli(tmp_path):
    pytest.importorskip("matplotlib")
    f = tmp_path / "m.json"
    f.write_text(json.dumps(MEASURED))
    p = subprocess.run([sys.executable, "-m", "sphgraph", "plot", "efficiency", str(f), "-o", str(tmp_path / "m.png")],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "m.png").exists()
    p = subprocess.run([sys.executable, "-m", "sphgraph", "plot", "efficiency", str(tmp_path / "none.json")],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and p.stderr.count("\n") == 1
