"""The contacts CLI: event formatting, filtering and the zenoh watch command."""

from typer.testing import CliRunner

from contactflow.fusion.cli import app, format_event, watch_events
from contactflow.fusion.messages import ContactEventMsg
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Event
from contactflow.nodes.transport import LocalTransport
from contactflow.nodes.wire import encode


def event(robot):
    return ContactEventMsg(event=Event.CONTACT_MADE, contact_id=3, robot=robot, link="thumb",
                           location=[0.5, 0.0, 0.8], likelihood=0.9, t=1.5)


def test_watch_filters_by_robot_and_rejects_garbage():
    ks = KeySpace("lab")
    bus = LocalTransport()
    got, errors = [], []
    sub = watch_events(bus, ks, "r1", got.append, errors.append)
    bus.publisher(ks.fused("r1", "events"))(encode(event("r1")))
    bus.publisher(ks.fused("r2", "events"))(encode(event("r2")))
    bus.publisher(ks.fused("r1", "events"))(b"\x00garbage")
    sub.close()
    assert [m.robot for m in got] == ["r1"] and len(errors) == 1
    text = format_event(got[0])
    assert "contact_made" in text and "r1/thumb" in text and "+0.500" in text


def test_cli_help_lists_watch():
    result = CliRunner().invoke(app, ["--help"])
    assert result.exit_code == 0 and "watch" in result.output


def test_watch_prints_events_from_zenoh():
    import threading

    from contactflow.nodes.procs import free_port
    from contactflow.nodes.transport import ZenohSettings, ZenohTransport

    port = free_port()
    ks = KeySpace("clitest")
    bus = ZenohTransport(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",))).open()
    pub = bus.publisher(ks.fused("r1", "events"))
    stop = threading.Event()

    def talk():
        while not stop.wait(0.05):
            pub(encode(event("r1")))

    th = threading.Thread(target=talk, daemon=True)
    th.start()
    try:
        result = CliRunner().invoke(app, ["watch", "r1", "--site", "clitest", "--connect",
                                          f"tcp/127.0.0.1:{port}", "--duration", "2.0"])
    finally:
        stop.set()
        th.join()
        bus.close()
    assert result.exit_code == 0, result.output
    assert "contact_made" in result.output and "r1/thumb" in result.output
