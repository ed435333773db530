"""The embodiments CLI lists, shows and composes robots."""

from __future__ import annotations

from typer.testing import CliRunner

from contactflow.embodiments.cli import app


def test_list_show_and_urdf(tmp_path):
    runner = CliRunner()
    out = runner.invoke(app, ["list"], env={"COLUMNS": "200"})
    assert out.exit_code == 0 and "tombatossals" in out.output and "baxter" in out.output
    out = runner.invoke(app, ["show", "melfa"], env={"COLUMNS": "200"})
    assert out.exit_code == 0 and "panda_hand_tcp" in out.output
    out = runner.invoke(app, ["urdf", "melfa", "--out-dir", str(tmp_path)])
    assert out.exit_code == 0 and list(tmp_path.glob("melfa-*.urdf"))
    out = runner.invoke(app, ["show", "r2d2"])
    assert out.exit_code == 2 and "unknown robot" in out.output
