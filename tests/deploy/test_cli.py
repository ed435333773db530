"""The ``contactflow`` CLI in-process (typer's CliRunner): new, ctl, echo, bench messaging."""

import json
import sys

import pytest
import yaml
from rich.console import Console
from typer.testing import CliRunner

from contactflow.deploy import cli
from contactflow.nodes.clock import SimClock
from contactflow.nodes.config import ConfigError, load_node_config
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Command, EventMsg, Vector
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for
from contactflow.nodes.status import Event, Status
from contactflow.nodes.transport import LocalTransport, ZenohSettings, ZenohTransport
from contactflow.nodes.wire import decode_any

SITE = "clitest"
KS = KeySpace(SITE)
runner = CliRunner()


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    """Print without wrapping, so a key expression stays on one line of the captured output."""
    monkeypatch.setattr(cli, "console", Console(width=400, soft_wrap=True))


def invoke(*args):
    return runner.invoke(cli.app, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture
def forget_generated():
    """Generated modules are imported by file name; forget them so each test imports its own."""
    yield
    sys.modules.pop("my_filter", None)


def test_new_primitive_writes_a_module_that_loads_next_to_its_config_and_runs(tmp_path, forget_generated):
    out = tmp_path / "gen"
    result = invoke("new", "primitive", "my_filter", "--out", out)
    assert result.exit_code == 0, result.output
    conf = out / "my_filter.config.yaml"
    assert {p.name for p in out.iterdir()} >= {"my_filter.py", "my_filter.description.yaml", conf.name}
    description = yaml.safe_load((out / "my_filter.description.yaml").read_text())
    assert description["layer"] == "primitive" and description["params"]["gain"] == 1.0

    cfg = load_node_config(conf)  # type "my_filter:MyFilter" is nowhere on sys.path but next to the file
    mod_cfg = next(m for m in cfg.modules if m.name == "my_filter")
    assert mod_cfg.cls.__name__ == "MyFilter" and not mod_cfg.autostart

    bus = LocalTransport()
    seen = []
    bus.subscribe("cf/**", lambda k, p: seen.append((k, decode_any(p))))
    clock = SimClock(bus, cfg.keyspace)
    host = ModuleHost(cfg, bus, clock)
    for m in cfg.modules:
        host.add(m)
    host.start_autostart()
    assert host.send_control("my_filter", Command.RUN, {"gain": "2"}).ok
    for i in range(1, 101):
        clock.advance(i * 0.01)
        host.tick()
    inputs = {m.hdr.id: m for k, m in seen if k.endswith("/source/out/signal")}
    outputs = [m for k, m in seen if k.endswith("/my_filter/out/out")]
    assert len(outputs) == 10
    for o in outputs:
        assert o.values == [2 * v for v in inputs[o.hdr.inputs[0]].values]
    assert [m.event for _, m in seen if isinstance(m, EventMsg)] == [Event.SUCCESS]
    assert host.modules[("site", "my_filter")].module.state == Status.SUCCESS


def test_new_refuses_a_bad_kind_or_name_and_an_existing_module(tmp_path):
    assert invoke("new", "widget", "x", "--out", tmp_path).exit_code == 2
    bad = invoke("new", "service", "My-Filter", "--out", tmp_path)
    assert bad.exit_code == 2 and "lower_snake_case" in bad.output
    assert invoke("new", "service", "twice", "--out", tmp_path).exit_code == 0
    again = invoke("new", "service", "twice", "--out", tmp_path)
    assert again.exit_code == 2 and "not overwriting" in again.output


def test_a_module_type_found_neither_installed_nor_next_to_the_config_names_both_places(tmp_path):
    conf = tmp_path / "node.yaml"
    conf.write_text("node: n\nmodules:\n  - {name: x, type: 'absent_module:Thing'}\n")
    with pytest.raises(ConfigError) as err:
        load_node_config(conf)
    text = str(err.value)
    assert text.startswith(f"{conf}:3: modules[0].type:") and f"also looked in {tmp_path}" in text


@pytest.fixture(scope="module")
def generated_node(tmp_path_factory):
    """A node process running the configuration ``contactflow new`` wrote, on a free port."""
    out = tmp_path_factory.mktemp("node")
    assert invoke("new", "primitive", "my_filter", "--out", out).exit_code == 0
    conf = out / "my_filter.config.yaml"
    config = yaml.safe_load(conf.read_text())
    port = free_port()
    config["site"] = SITE
    config["zenoh"]["listen"] = [f"tcp/127.0.0.1:{port}"]
    conf.write_text(yaml.safe_dump(config, sort_keys=False))
    proc = spawn_node(conf, out / "node.log", env={"PYTHONPATH": ""})
    tool = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",))).open()
    try:
        up = wait_for(lambda: len(tool.alive(KS.alive_module())) == 2, timeout=30)
    finally:
        tool.close()
    if not up:
        stop_process(proc)
        raise AssertionError((out / "node.log").read_text()[-3000:])
    yield f"tcp/127.0.0.1:{port}"
    sys.modules.pop("my_filter", None)
    assert stop_process(proc) == 0


def test_ctl_sets_parameters_runs_and_describes_a_module_in_a_node_process(generated_node):
    common = ("--site", SITE, "--connect", generated_node)
    ok = invoke("ctl", "my_filter", "set", "gain=3", *common)
    assert ok.exit_code == 0, ok.output
    assert "/my_filter/ctl: ok" in ok.output and "'gain': 3.0" in ok.output
    bad = invoke("ctl", "my_filter", "set", "gain=much", *common)
    assert bad.exit_code == 1 and "gain" in bad.output and ": ok" not in bad.output
    assert invoke("ctl", "my_filter", "jump", *common).exit_code == 2
    assert invoke("ctl", "my_filter", "set", "gain", *common).exit_code == 2
    nobody = invoke("ctl", "nobody", "run", *common)
    assert nobody.exit_code == 1 and "no module answers" in nobody.output
    run = invoke("ctl", "my_filter", "run", *common)
    assert run.exit_code == 0 and "state=running" in run.output
    finished = []
    assert wait_for(lambda: finished.append(invoke("ctl", "my_filter", "describe", *common).output)
                    or "state=success" in finished[-1], timeout=10), finished[-1]
    assert "layer: primitive" in finished[-1]


def test_echo_prints_decoded_messages_of_a_node_process(generated_node):
    key = KS.output("site", "*", "source", "signal")
    result = invoke("echo", key, "--count", 3, "--duration", 10, "--connect", generated_node)
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.startswith(f"cf/{SITE}/m/site/my_filter_node/source")]
    assert len(lines) == 3 and all("'type': 'vector'" in line and "'values': [" in line for line in lines)
    raw = invoke("echo", key, "--count", 1, "--duration", 10, "--raw", "--connect", generated_node)
    doc = json.loads(raw.output)
    assert doc["msg"]["type"] == "vector" and doc["msg"]["hdr"]["source"] == "site/my_filter_node/source/signal"
    assert isinstance(Vector(values=doc["msg"]["values"]).values[0], float)


def test_bench_jobs_is_refused_by_a_benchmark_that_measures_processes_itself(tmp_path):
    result = invoke("bench", "messaging", "--quick", "--jobs", 2, "--out", tmp_path)
    assert result.exit_code == 2 and "does not take --jobs" in result.output, result.output
    assert not (tmp_path / "messaging.json").exists()


def test_bench_rig_reaches_the_contacts_bench_and_is_refused_where_it_means_nothing(tmp_path):
    refused = invoke("bench", "grasp", "--quick", "--rig", "melfa", "--out", tmp_path)
    assert refused.exit_code == 2 and "does not take --rig" in refused.output, refused.output
    unknown = invoke("bench", "contacts", "--quick", "--rig", "ur5", "--out", tmp_path)  # refused by the bench itself
    assert unknown.exit_code == 2 and "--rig 'ur5' is not one of" in unknown.output, unknown.output


def test_bench_empty_box_runs_chosen_strategies_from_a_chosen_seed_within_the_caps(tmp_path):
    refused = invoke("bench", "messaging", "--quick", "--max-time", 5, "--out", tmp_path)
    assert refused.exit_code == 2 and "does not take --max-time" in refused.output, refused.output
    result = invoke("bench", "empty-box", "--quick", "--strategy", "vision", "--strategy", "random", "--first-seed", 7,
                    "--runs", 2, "--max-time", 4, "--max-attempts", 1, "--out", tmp_path)
    assert result.exit_code == 0, result.output
    saved = json.loads((tmp_path / "empty_box.json").read_text())
    assert [(r["strategy"], r["seed"]) for r in saved["runs"]] == [("vision", 7), ("vision", 8), ("random", 7), ("random", 8)]
    assert [r["method"] for r in saved["rows"]] == ["vision", "random"] and saved["first_seed"] == 7
    assert saved["max_time"] == 4.0 and saved["max_attempts"] == 1
    assert all(r["time"] <= 4.0 + 0.5 and r["attempts"] <= 2 for r in saved["runs"]), saved["runs"]
    md = (tmp_path / "empty_box.md").read_text()
    assert "(seeds 7-8)" in md and "4 s of simulated time or 1 grasp attempt " in md
    bad = invoke("bench", "empty-box", "--quick", "--strategy", "telepathy", "--out", tmp_path / "bad")
    assert bad.exit_code == 2 and "unknown strategy 'telepathy'" in bad.output, bad.output
    assert not (tmp_path / "bad" / "empty_box.json").exists()


def test_bench_catch_zone_is_listed_and_refuses_the_empty_box_caps(tmp_path):
    listed = invoke("bench", "nonesuch", "--out", tmp_path)
    assert listed.exit_code == 2 and "catch-zone" in listed.output, listed.output
    refused = invoke("bench", "catch-zone", "--quick", "--runs", 3, "--out", tmp_path)
    assert refused.exit_code == 2 and "does not take --runs" in refused.output, refused.output
    assert not (tmp_path / "catch_zone.json").exists()
    refused = invoke("bench", "catch-zone", "--quick", "--trials", 3, "--out", tmp_path)
    assert refused.exit_code == 2 and "does not take --trials" in refused.output, refused.output  # the grasp bench's


def test_bench_messaging_quick_writes_its_json(tmp_path):
    result = invoke("bench", "messaging", "--quick", "--out", tmp_path)
    assert result.exit_code == 0, result.output
    saved = json.loads((tmp_path / "messaging.json").read_text())
    assert saved["quick"] is True
    assert [r["payload"] for r in saved["rows"]] == ["64B", "4KiB", "64KiB", "1MiB"]
    for r in saved["rows"]:
        assert r["raw_msgs_per_s"] > 0 and r["cf_msgs_per_s"] > 0, r
        assert 0 < r["cf_p50_us"] <= r["cf_p99_us"] and 0 < r["raw_p50_us"] <= r["raw_p99_us"], r
