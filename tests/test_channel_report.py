"""What a person sees of the shared radio channel (``medium:``, docs/channel.md): the channel
line of ``dkfsim run``'s summary and the "Shared channel" table of ``dkfsim report``, both read
against the run's own summary.json; a run without a medium shows neither."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest
from test_report import Page, close

from dkfsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
CHANNEL = ROOT / "scenarios" / "channel_its_g5.yaml"
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"

LINE = re.compile(r"^channel: utilisation (\S+), (\d+) frames \((\S+) % collided, (\d+) dropped by full "
                  r"radio queues\), mean access delay (\S+) ms; background (\d+) frames on the air "
                  r"\((\d+) collided\)(?:, (\d+) refused by full queues)?$", re.M)


def run_cli(scenario: Path, out: Path) -> str:
    """``dkfsim run`` of 40 ticks; its console output."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert main(["run", str(scenario), "--steps", "40", "--save", "summary", "--out", str(out)]) == 0
    return text.getvalue()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("show")
    return {"channel": (run_cli(CHANNEL, d / "channel"), d / "channel"),
            "plain": (run_cli(CASE1, d / "plain"), d / "plain")}


def summary(folder: Path) -> dict:
    return json.loads((folder / "summary.json").read_text())


def test_console_channel_line_holds_the_dkfs_channel_numbers(runs):
    text, folder = runs["channel"]
    s = summary(folder)
    ch = s["traffic"]["fused"]["channel"]            # the scenario's DKF
    assert ch == s["packets"]["channel"]
    lines = LINE.findall(text)
    assert len(lines) == 1, text
    util, frames, collided, dropped, delay, bg_air, bg_collided, bg_dropped = lines[0]
    assert ch["frames"] > 0 and ch["frames_collided"] > 0    # a run that exercises the line
    assert float(util) == pytest.approx(ch["utilisation"], rel=5e-3)      # 3 significant digits
    assert int(frames) == ch["frames"]
    assert float(collided) == pytest.approx(100 * ch["frames_collided"] / ch["frames"], rel=5e-3)
    assert int(dropped) == ch["frames_dropped"]
    assert float(delay) == pytest.approx(1e3 * ch["access_delay_mean"], rel=5e-3)
    # on the air: the background frames that were sent whole and those that collided
    assert (int(bg_air), int(bg_collided)) == (ch["background_sent"] + ch["background_collided"],
                                               ch["background_collided"])
    assert int(bg_dropped or 0) == ch["background_dropped"]
    # the channel line follows the packets line, as its companion
    assert text.index("packets: sent") < text.index("channel: utilisation")


def test_report_shows_each_estimators_channel(runs):
    _, folder = runs["channel"]
    assert main(["report", str(folder)]) == 0
    html_text = (folder / "report.html").read_text()
    page = Page(html_text)
    assert "Shared channel" in html_text
    head, *body = page.tables["channel"]
    assert head == ["estimator", "utilisation", "frames", "collided [%]", "dropped [frames]",
                    "background on air", "background collided", "mean access delay [ms]"]
    s = summary(folder)
    blocks = {"DKF (anti-delay)": s["packets"]["channel"]}
    blocks.update((name, t["channel"]) for name, t in s["traffic"].items()
                  if t and t.get("channel") and name not in ("fused", "local"))
    assert [r[0] for r in body] == list(blocks)
    assert "centralized" not in blocks and "fusion_centre" in blocks    # no channel / shares the DKF's
    for row in body:
        ch = blocks[row[0]]
        want = (ch["utilisation"], ch["frames"], 100 * ch["frames_collided"] / ch["frames"],
                ch["frames_dropped"], ch["background_sent"] + ch["background_collided"], ch["background_collided"],
                1e3 * ch["access_delay_mean"])
        assert all(close(cell, v) for cell, v in zip(row[1:], want, strict=True)), (row, want)
    # the DKF's utilisation as the page prints every number: 6 significant digits
    assert f"{s['packets']['channel']['utilisation']:.6g}" == body[0][1]
    # the fusion centre's frames go through the DKF's copy of the channel: the same channel
    fc = next(r for r in body if r[0] == "fusion_centre")
    assert fc[1] == body[0][1]


def test_run_without_medium_shows_no_channel(runs):
    text, folder = runs["plain"]
    assert "packets: sent" in text
    assert "channel:" not in text and not LINE.search(text)
    assert main(["report", str(folder)]) == 0
    html_text = (folder / "report.html").read_text()
    assert "channel" not in Page(html_text).tables
    assert "Shared channel" not in html_text


@pytest.mark.parametrize("where, value, words", [
    (("packets", "channel", "frames"), "many", "packets.channel.frames"),
    (("traffic", "kcf", "channel", "utilisation"), -0.5, "traffic.kcf.channel.utilisation"),
    (("traffic", "fusion_centre", "channel", "access_delay_mean"), None, "fusion_centre.channel.access_delay_mean"),
])
def test_a_damaged_channel_block_is_one_message_exit_2(runs, tmp_path, capsys, where, value, words):
    _, folder = runs["channel"]
    s = summary(folder)
    block = s
    for key in where[:-1]:
        block = block[key]
    block[where[-1]] = value
    (tmp_path / "summary.json").write_text(json.dumps(s))
    (tmp_path / "rows.csv").write_bytes((folder / "rows.csv").read_bytes())
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert words in err and str(tmp_path / "summary.json") in err and "Traceback" not in err
