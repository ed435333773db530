"""The generated field tables (docs/messages.md) match the msgspec structs, and cover every field."""

import msgspec
import msgspec.inspect as mi
from typer.testing import CliRunner

from contactflow.nodes import fieldtables
from contactflow.nodes.fieldtables import DOC, message_types, missing, render
from contactflow.nodes.protocol_cli import app


def test_the_committed_document_is_what_the_code_generates():
    assert DOC.read_text() == render(), "docs/messages.md is stale: run `contactflow protocol fields`"


def test_every_type_and_field_has_a_meaning():
    assert missing() == []


def test_every_wire_message_and_every_field_has_a_row():
    text = render()
    types = message_types()
    assert len(types) >= 45
    for cls in types:
        section = text.split(f"### `{cls.tag()}`\n", 1)[1].split("\n### ", 1)[0]
        for f in mi.type_info(cls).fields:
            assert f"| `{f.encode_name}` |" in section, (cls.tag(), f.name)


def test_a_row_gives_type_default_and_the_comment_of_the_source():
    text = render()
    arm = text.split("### `arm_command`\n", 1)[1].split("\n### ", 1)[0]
    assert "| `values` | [NDArray](#ndarray) or nil | nil | float64, (2, n) for a target |" in arm
    assert "[ArmCommandKind](#armcommandkind): one of `target`" in arm
    hand = text.split("### `hand_command`\n", 1)[1].split("\n### ", 1)[0]
    assert "| `effort` | float | `1.0` | fraction of the fingers' force limit, (0, 1] |" in hand
    assert "| `tare` | zero the arm's wrist F/T sensor |" in text
    assert "### Header\n" in text and "### MsgId\n" in text  # structures inside messages get their own table


class _Probe(msgspec.Struct, kw_only=True):
    """A probe."""

    a: int  # m, the first
    b: list[float | str] = []
    c: str = "x"  # why


def test_comments_and_types_are_read_from_the_struct_itself():
    assert fieldtables._comments(_Probe) == {"a": "m, the first", "b": "", "c": "why"}
    rows = fieldtables._table(_Probe, [])
    assert "| `a` | int | required | m, the first |" in rows
    assert "| `b` | list of (float or str) | empty |  |" in rows
    assert '| `c` | str | `"x"` | why |' in rows


def test_the_check_command_fails_on_a_stale_document(tmp_path):
    stale = tmp_path / "messages.md"
    stale.write_text(render().replace("zero the arm's wrist F/T sensor", "zero it"))
    runner = CliRunner()
    res = runner.invoke(app, ["fields", "--out", str(stale), "--check"])
    assert res.exit_code == 1 and "differs" in res.output
    assert runner.invoke(app, ["fields", "--out", str(stale)]).exit_code == 0
    assert runner.invoke(app, ["fields", "--out", str(stale), "--check"]).exit_code == 0
    assert stale.read_text() == render()
