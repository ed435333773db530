"""The ``atd`` CLI (abstraction.atd_cli): check, translate for every robot, and refusals with exit codes."""

from __future__ import annotations

from typer.testing import CliRunner

from contactflow.abstraction.atd_cli import app
from contactflow.abstraction.examples import path

runner = CliRunner()


def test_check_and_translate_examples():
    res = runner.invoke(app, ["check", str(path("fig7_2.xml"))])
    assert res.exit_code == 0, res.output
    assert "lift_object" in res.output and "0.2 0.6 0.25" in res.output
    res = runner.invoke(app, ["translate", str(path("pick_place_behind.xml"))])
    assert res.exit_code == 0, res.output
    for robot in ("tombatossals", "melfa", "baxter"):
        assert f"{robot}: ESTD" in res.output
    assert "robust_grasp" in res.output and "close_until_force" in res.output
    res = runner.invoke(app, ["translate", str(path("fig7_2.xml")), "-r", "melfa", "--yaml"])
    assert res.exit_code == 0 and "primitive: close_until_force" in res.output


def test_refusals_exit_nonzero(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text(path("fig7_2.xml").read_text().replace('type="grasp"', 'type="juggle"'))
    res = runner.invoke(app, ["check", str(bad)])
    assert res.exit_code == 2 and "unknown abstract primitive 'juggle'" in res.output
    wipe = tmp_path / "wipe.xml"
    wipe.write_text("""<statemachine><state name="w" type="slide"><target>0.2 0.5 0.05</target></state>
<state name="d" type="success"/><transition origin="w" destination="d"><success/></transition>
</statemachine>""")
    res = runner.invoke(app, ["translate", str(wipe)])
    assert res.exit_code == 1 and "melfa refuses" in res.output and "cannot slide" in res.output
