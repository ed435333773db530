"""Node configuration: valid files load; invalid ones fail with file, line and field."""

import pytest

from contactflow.nodes.config import load_node_config, parse_node_config
from contactflow.nodes.yamldoc import ConfigError, YamlDoc

GOOD = """\
site: lab
node: n1
modules:
  - name: src
    type: signal_source
    params: {rate_hz: 20}
  - name: lp
    type: lowpass
    inputs: {in: src.signal}
"""


def test_good_config_loads(tmp_path):
    p = tmp_path / "n.yaml"
    p.write_text(GOOD)
    cfg = load_node_config(p)
    assert [m.name for m in cfg.modules] == ["src", "lp"]
    assert cfg.modules[0].params.rate_hz == 20.0
    assert cfg.modules[1].inputs["in"].module == "src"
    assert cfg.zenoh.multicast_scouting is False


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        (GOOD.replace("rate_hz: 20", "rate_hz: fast"), 6, "modules[0].params.rate_hz"),
        (GOOD.replace("rate_hz: 20", "rate_hz: .nan"), 6, "modules[0].params.rate_hz"),
        (GOOD.replace("rate_hz: 20", "rate_hz: -5"), 6, "positive finite rate"),
        (GOOD.replace("type: lowpass", "type: nosuch"), 8, "unknown module type 'nosuch'"),
        (GOOD.replace("in: src.signal", "bogus: src.signal"), 9, "has no input 'bogus'"),
        (GOOD.replace("in: src.signal", "in: nodot"), 9, "modules[1].inputs.in"),
        (GOOD.replace("in: src.signal", "in: src.nosuch"), 9, "module 'src' (SignalSource) has no output 'nosuch'"),
        (GOOD + "colour: red\n", 10, "colour: unknown field"),
        (GOOD.replace("node: n1", "node: a/b"), 2, "node"),
        (GOOD.replace("    params: {rate_hz: 20}", "    params: {rate_hz: 20, gain: 3}"), 6, "gain"),
        ("site: [unclosed\n", 2, "not valid YAML"),
    ],
)
def test_bad_config_names_file_line_and_field(text, line, fragment):
    with pytest.raises(ConfigError) as err:
        parse_node_config(YamlDoc.parse(text, "cfg/node.yaml"))
    msg = str(err.value)
    assert msg.startswith(f"cfg/node.yaml:{line}:"), msg
    assert fragment in msg


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_node_config(tmp_path / "absent.yaml")
