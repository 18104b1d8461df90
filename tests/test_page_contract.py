"""The page's contract (shared/page.py) is the one the page uses: its generated copy in the page's
folder is current, every message the scripts handle is a down message and every field they read of
it is one of its fields, every message they send is an up message with only its fields, every down
message a script can receive has its handler, and docs/contract.md lists every message."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from shared import page

ROOT = Path(__file__).resolve().parent.parent
STATIC = ROOT / "services/human/static"
SCRIPTS = {"tsf.js": STATIC / "tsf.js", "dashboard.js": STATIC / "dashboard.js"}
DASHBOARD_ONLY = {"study"}  # down messages only the dashboard's script receives


def source(name: str) -> str:
    """A script without its comments and string contents' line breaks (what the checks read)."""
    return re.sub(r"//[^\n]*", "", SCRIPTS[name].read_text())


def handlers(text: str) -> dict[str, str]:
    """tsf.js's handlers: type -> the handler's body."""
    block = text.split("const handlers = {", 1)[1]
    starts = list(re.finditer(r"^  (\w+)\((\w*)\) \{", block, re.MULTILINE))
    ends = [m.start() for m in starts[1:]] + [block.index("\n};")]
    return {m[1]: (m[2], block[m.end() : end]) for m, end in zip(starts, ends, strict=True)}


def calls(text: str, name: str) -> list[str]:
    """The argument text of every call of `name(...)` (balanced parentheses)."""
    found = []
    for match in re.finditer(rf"\b{name}\(", text):
        depth, i = 1, match.end()
        while depth:
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            i += 1
        found.append(text[match.end() : i - 1])
    return found


def sent(text: str) -> list[tuple[str, set[str]]]:
    """Every message a script sends: its type and the fields it names (keyed or shorthand)."""
    out = []
    for body in [*calls(text, "send"), *calls(text, "socket.send")]:
        kind = re.search(r'type: "(\w+)"', body)
        if kind is None:  # socket.send(JSON.stringify(...)) wraps a send's object
            continue
        stripped = re.sub(r'"[^"]*"|`[^`]*`', '""', body)
        keyed = set(re.findall(r"(\w+):", stripped))
        shorthand = set(re.findall(r"[{,]\s*(\w+)\s*(?=[,}])", stripped))
        out.append((kind[1], (keyed | shorthand) - {"type"}))
    return out


def test_the_pages_copy_of_the_contract_is_generated_from_it() -> None:
    assert (ROOT / page.CONTRACT_JS).read_text() == page.contract_js()
    assert {name.split(".")[0] for name in ("contract.js",)} <= {p.stem for p in STATIC.iterdir()}


def test_every_message_tsf_js_handles_is_in_the_contract_with_the_fields_it_reads() -> None:
    found = handlers(source("tsf.js"))
    assert {"state", "end", "trial", "done", "stopped", "watching"} <= set(found)  # the parser sees them
    for kind, (argument, body) in found.items():
        assert kind in page.DOWN, f"tsf.js handles {kind!r}, which is no down message of shared/page.py"
        read = set(re.findall(rf"\b{argument}\.(\w+)", body)) if argument else set()
        assert read <= set(page.CONTRACT["down"][kind]), (
            f"{kind}: tsf.js reads {read - set(page.CONTRACT['down'][kind])}"
        )
    unhandled = set(page.DOWN) - set(found) - DASHBOARD_ONLY
    assert not unhandled, f"down messages tsf.js cannot show: {unhandled}"


def test_the_dashboard_reads_its_messages_fields() -> None:
    text = source("dashboard.js")
    kinds = set(re.findall(r'message\.type === "(\w+)"', text))
    assert kinds == {"refused", "study"} and kinds <= set(page.DOWN)
    assert set(re.findall(r"\bo\.(\w+)", text)) <= set(page.CONTRACT["down"]["study"])
    assert set(re.findall(r"message\.(\w+)", text)) - {"type"} <= set(page.CONTRACT["down"]["refused"])


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_message_a_script_sends_is_an_up_message_with_its_fields(name: str) -> None:
    messages = sent(source(name))
    assert messages, "the parser sees the sends"
    for kind, fields in messages:
        assert kind in page.UP, f"{name} sends {kind!r}, which is no up message"
        assert fields <= set(page.CONTRACT["up"][kind]), f"{name}: {kind} with {fields}"


def test_what_the_scripts_send_decodes_and_what_they_must_not_is_refused() -> None:
    hello = {"type": "hello", "worker": "W-1", "sig": "ab", "link": {"STUDY_ID": "S"}}
    assert page.decode(json.dumps(hello), ("hello",)) == page.Hello(
        worker="W-1", sig="ab", link={"STUDY_ID": "S"}
    )
    with pytest.raises(page.PageError, match="shape"):
        page.decode(json.dumps({**hello, "admin": True}), ("hello",))
    with pytest.raises(page.PageError, match="type"):
        page.decode(json.dumps({"type": "done", "text": "", "code": "", "redirect": ""}), ("hello",))
    done = page.Done(text="Thanks.", code="C0DE", redirect="")
    assert page.decode_down(done.encode()) == done
    with pytest.raises(page.PageError, match="missing field 'code'"):
        page.decode_down(json.dumps({"type": "done", "text": "Thanks.", "redirect": ""}))


def test_docs_list_every_message_of_the_page() -> None:
    text = (ROOT / "docs/contract.md").read_text().split("## The page's messages", 1)[1]
    listed = set(re.findall(r"^\| `(\w+)` \| (up|down) ", text, re.MULTILINE))
    assert listed == {(kind, "up") for kind in page.UP} | {(kind, "down") for kind in page.DOWN}
