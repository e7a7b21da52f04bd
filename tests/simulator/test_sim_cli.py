"""`slidewatch simulate` as a click command."""

import json

from click.testing import CliRunner

from worker.commands.simulate import simulate_command
from worker.simulator.manifest import Manifest


def test_simulate_command_writes_a_manifest(tmp_path):
    out = tmp_path / "sim"
    result = CliRunner().invoke(
        simulate_command,
        ["--scenario", "hillslope", "--out", str(out), "--seed", "2", "--survey", "none"],
    )
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output[result.output.index("{") :])
    assert summary["steps"] == 2 and summary["events"] == 2
    m = Manifest.load(out)
    assert m.data["scenario"] == "hillslope"
    assert m.data["grid"]["res_m"] == 0.2
    dsm_minus_dem = m.data["steps"][0]["trees"]["conifer"]
    assert dsm_minus_dem > 1000
    reg = {r["pattern"]: r["shift_enu_m"] for r in m.data["registration"]}
    assert reg["C"] == [1.0, 1.0, 1.2]  # ten times the paper's one-tenth-scale shifts
    ev = m.step(2)["events"]
    assert max(e["max_depth_m"] for e in ev) > 8.0  # real scale: 10-17 m deep
    assert m.step(2)["fallen_trees"] > 0


def test_bad_arguments_fail_cleanly(tmp_path):
    r = CliRunner().invoke(simulate_command, ["--scenario", "moon", "--out", str(tmp_path)])
    assert r.exit_code == 2
    assert "moon" in r.output
    r = CliRunner().invoke(simulate_command, ["--help"])
    assert r.exit_code == 0 and "--video-seconds" in r.output
    # A rolling shutter slower than a frame: refused, naming the option and the limit.
    args = ["--scenario", "paper-mounds", "--out", str(tmp_path / "rs"), "--survey", "none"]
    r = CliRunner().invoke(simulate_command, [*args, "--rolling-shutter", "0.05"])
    assert r.exit_code != 0 and "rolling_shutter_s" in r.output and "0.0333" in r.output
    r = CliRunner().invoke(simulate_command, [*args, "--sun-elevation", "0"])
    assert r.exit_code == 2 and "--sun-elevation" in r.output
