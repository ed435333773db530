"""Local launch on loopback: `deploy up --local --detach`, `status` and `stop` from another shell; back-off."""

import threading
import time

import yaml
from typer.testing import CliRunner

from contactflow.deploy.health import open_observer
from contactflow.deploy.launcher import Launch
from contactflow.deploy.launcher_cli import app
from contactflow.deploy.manifest import DEFAULT_MANIFEST, NodeSpec, load_manifest
from contactflow.deploy.supervisor import Supervisor, pid_alive, read_state
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port_block


def test_up_local_with_a_router_then_status_and_stop_from_another_shell(tmp_path):
    port = free_port_block(32)
    manifest = tmp_path / "two.yaml"
    manifest.write_text(yaml.safe_dump({
        "site": "localtest", "zenoh": {"port": port, "topology": "routers", "routers": ["b"]},
        "hosts": {
            "a": {"nodes": {"na": {"robot": "r", "modules": [{"name": "s", "type": "signal_source"}]}}},
            "b": {"nodes": {"nb": {"robot": "r", "modules": [{"name": "f", "type": "lowpass", "inputs": {"in": "s.signal"}}]}}},
        }}))
    run = tmp_path / "run"
    cli = CliRunner()
    # the form, without `up`; `again` below uses the explicit one
    res = cli.invoke(app, [str(manifest), "--local", "--run-dir", str(run), "--detach", "--wait", "40"])
    try:
        assert res.exit_code == 0, res.output
        assert "3/3 nodes alive" in res.output, res.output
        st = read_state(run / "local")
        assert st is not None and pid_alive(st.pid) and all(pid_alive(n.pid) for n in st.nodes.values())
        assert (run / "local" / "logs" / "na.log").exists()
        res = cli.invoke(app, ["status", str(manifest), "--run-dir", str(run)])
        assert res.exit_code == 0 and "3/3 nodes alive" in res.output, res.output
        again = cli.invoke(app, ["up", str(manifest), "--local", "--run-dir", str(run)])
        assert again.exit_code == 1 and "already supervised" in again.output
    finally:
        res = cli.invoke(app, ["stop", str(manifest), "--run-dir", str(run)])
    assert res.exit_code == 0 and "supervisor" in res.output, res.output
    st = read_state(run / "local")
    assert st.state == "stopped" and not pid_alive(st.pid)
    assert not any(pid_alive(n.pid) for n in st.nodes.values())
    res = cli.invoke(app, ["status", str(manifest), "--run-dir", str(run), "--timeout", "0.3"])
    assert res.exit_code == 1 and "0/3 nodes alive" in res.output


def test_the_default_manifest_comes_up_locally_with_its_robots_and_broker(tmp_path):
    port = free_port_block(32)
    manifest = tmp_path / "default.yaml"
    manifest.write_text(DEFAULT_MANIFEST.read_text().replace("port: 7450", f"port: {port}"))
    m = load_manifest(manifest)
    run = tmp_path / "run"
    cli = CliRunner()
    try:
        res = cli.invoke(app, [str(manifest), "--local", "--run-dir", str(run), "--detach", "--wait", "60"])
        assert res.exit_code == 0 and "8/8 nodes alive" in res.output, res.output
        ks = KeySpace(m.site)
        obs = open_observer(m, local=True)
        try:
            robots = {k.rsplit("/", 1)[-1] for k in obs.alive(ks.alive_robot(), timeout=1.0)}
            modules = {k.rsplit("/", 1)[-1] for k in obs.alive(ks.alive_module(), timeout=1.0)}
        finally:
            obs.close()
        assert robots == {"tombatossals", "melfa", "baxter"}, robots
        assert {"broker", "agent", "world", "robust_grasp", "cloud", "plane", "roi", "objects", "shape"} <= modules, modules
        logs = "".join(f.read_text() for f in (run / "local" / "logs").glob("*.log"))
        assert "Traceback" not in logs, logs[-3000:]
    finally:
        cli.invoke(app, ["stop", str(manifest), "--run-dir", str(run)])


def test_a_crashing_node_is_restarted_with_growing_back_off(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("node: x\nmodules: [{name: m, type: no_such_type}]\n")
    spec = NodeSpec("h", "x", "site", "wall", 7000, (), ())
    sup = Supervisor([Launch(spec, bad, tmp_path / "x.log", "tcp/127.0.0.1:7000")], tmp_path / "scope", "m.yaml",
                     base_delay=0.1, max_delay=0.4, stable_s=30.0)
    stop = threading.Event()
    sup.start()
    t = threading.Thread(target=sup.run, args=(stop, 0.02))
    t.start()
    try:
        end = time.monotonic() + 30
        while time.monotonic() < end and sup.state.nodes["x"].restarts < 2:
            time.sleep(0.05)
    finally:
        stop.set()
        t.join(15)
    ns = read_state(tmp_path / "scope").nodes["x"]
    assert ns.restarts >= 2 and ns.failures >= 2
    assert ns.state == "stopped"
    log = (tmp_path / "x.log").read_text()
    assert log.count("--- supervisor: start #") >= 3 and "no_such_type" in log
