"""The dashboard's page in a real browser: Debian's chromium, headless, driven by playwright.

A wall-clock `hils run --dashboard` against `hils emulator serve`: the page shows the phases change
and the manager's state; the emulator is then stopped (SIGSTOP), the page shows TIMEOUT with its
reason, the emulator continues and the page's Recover button brings the manager back to IDLE. The
finished run is then replayed with `hils view`: the slider moves it, Play runs it at --realtime.
A corridor run (four controllers served by one `hils emulator serve --scenario corridor`) shows four
panels, west to east, one of them alone in TIMEOUT and recovered from its own panel, live and replayed.
Screenshots are kept in the test's tmp dir (``live.png``, ``timeout.png``, ``replay.png``,
``corridor.png``, ``corridor-replay.png``). Nothing downloads a browser: chromium comes from the
Makefile's deps target.
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import json
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page, sync_playwright

from harness.bench.processes import start_emulator
from tests.hils.dashboard.test_dashboard import get, page_root, secret_of, start_dashboard, start_view

pytestmark = pytest.mark.browser

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    if not os.path.exists(CHROMIUM):
        pytest.fail(f"{CHROMIUM} missing: `make deps` installs Debian's chromium")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def shown(page: Page, within: str = "") -> dict[str, str]:
    """Each phase's indication on the page (``within``: a selector and a space, e.g. one panel's)."""
    return page.eval_on_selector_all(within + "[data-phase]", "els => Object.fromEntries(els.map(e => "
                                                              "[e.dataset.phase, e.dataset.shown]))")


def state(page: Page) -> str:
    return page.locator("[data-testid=manager-state]").inner_text()


def watch(page: Page, until, within: float, what: str) -> None:
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        if until():
            return
        page.wait_for_timeout(100)
    raise AssertionError(f"the page did not show {what} within {within} s")


def interrupt(proc: subprocess.Popen[str] | None) -> None:
    """Stop a run as Ctrl-C does (None: it never started)."""
    if proc is not None:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)


def test_live_page_shows_phases_change_timeout_and_recovery(tmp_path: Path, browser: Browser, paper_toml: str) -> None:
    # Decisions every 4 s instead of 10, so that phases change soon.
    config = tmp_path / "fast.toml"
    config.write_text(paper_toml.replace("control_interval = 10.0", "control_interval = 4.0"))
    served = start_emulator(tmp_path / "serve.log")
    run_dir = tmp_path / "run"
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    proc = None
    try:
        proc, url = start_dashboard(sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress", "--config",
                                    str(config), "--target",
                                    f"snmp://127.0.0.1:{served.port}?community=private&version=2c",
                                    "--duration", "120", "--recover-after", "-1", "--dashboard", "0",
                                    "--dashboard-control", "--out", str(run_dir))
        page.goto(url)
        assert "token" not in page.url  # kept by the tab, out of the address bar
        watch(page, lambda: "G" in shown(page).values(), 15, "a green phase")
        first = shown(page)
        greens_seen = {tuple(sorted(p for p, s in first.items() if s == "G"))}
        states_seen = {state(page)}
        nexts_seen: set[str] = set()

        def changed() -> bool:
            now = shown(page)
            greens_seen.add(tuple(sorted(p for p, s in now.items() if s == "G")))
            states_seen.add(state(page))
            # PhaseNext, read from the controller every second, shows while a ring clears.
            nexts_seen.update(page.eval_on_selector_all("[data-next]", "els => els.map(e => e.closest("
                                                        "'[data-phase]').dataset.phase)"))
            return len(greens_seen) > 1 and "ON_HOLD" in states_seen and "IDLE" in states_seen and bool(nexts_seen)

        watch(page, changed, 40, "the greens change, PhaseNext show and the manager go ON_HOLD and back to IDLE")
        assert page.locator("[data-testid=cabinet-note]").inner_text().startswith("WALK, FDW")
        assert "Y" in {*shown(page).values()} or len(greens_seen) > 1
        assert page.locator("#run").inner_text().startswith("paper four-leg intersection · wall-clock")
        assert page.locator("#commands tbody tr").count() >= 1
        page.screenshot(path=str(tmp_path / "live.png"), full_page=True)
        assert not page.locator("[data-testid=recover]").is_visible()  # nothing to recover yet

        served.proc.send_signal(signal.SIGSTOP)  # the controller stops answering
        try:
            watch(page, lambda: state(page) == "TIMEOUT", 20, "TIMEOUT")
            assert "communication" in page.locator("[data-testid=timeout-reason]").inner_text()
            assert page.locator("[data-testid=recover]").is_visible()
            page.screenshot(path=str(tmp_path / "timeout.png"), full_page=True)
        finally:
            served.proc.send_signal(signal.SIGCONT)
        # A page served from another port of this machine tries the Recover request as the attacker did
        # (no-cors: the browser sends it and hides only the answer, opaque): the manager stays in TIMEOUT.
        with elsewhere(tmp_path) as hostile_url:
            hostile = browser.new_page()
            hostile.goto(hostile_url)
            sent = hostile.evaluate("""async (root) => Promise.all([undefined, "recover"].map((body) =>
                fetch(root + "api/recover", { method: "POST", mode: "no-cors", body })
                    .then((res) => res.type, (error) => String(error))))""", page_root(url))
            hostile.close()
        assert sent == ["opaque", "opaque"]  # the requests reached the dashboard (the run's record shows they did
        assert state(page) == "TIMEOUT"        # nothing: one recovery, the Recover button's, below)
        page.locator("[data-testid=recover]").click()
        watch(page, lambda: state(page) in {"IDLE", "ON_HOLD"}, 20, "IDLE after Recover")
        assert page.locator("#recover-said").inner_text() == "requested"
        status, err = get(page_root(url) + "api/recover?intersection=J1", "POST", secret_of(url))
        assert status == 400 and "a run of one intersection" in err["error"]
    finally:
        page.close()
        interrupt(proc)
        served.stop()
    records = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    assert [r["reason"] for r in records if r["kind"] == "timeout_entered"] == ["communication"]
    assert [r["kind"] for r in records if r["kind"] in ("recovery_started", "recovered")] == ["recovery_started",
                                                                                             "recovered"]

    # The same run replayed: the slider moves the page to an instant of the run, half a second into the hold of its
    # first command (read from the run's record: how far the run had gone when the emulator was stopped depends on
    # how fast the page and the browser were, a busy machine's business).
    held = next(r["t"] for r in records if r["kind"] == "state" and r["to"] == "on_hold")
    at = round(held + 0.5, 1)
    shown_then = [r["to"] for r in records if r["kind"] == "state" and r["t"] <= at][-1]
    assert shown_then == "on_hold"
    view, url = start_view(str(run_dir), "--realtime", "10")
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    try:
        page.goto(url)
        watch(page, lambda: page.locator("[data-phase]").count() == 8, 15, "the phases")
        page.locator("[data-testid=slider]").fill(str(at))
        watch(page, lambda: page.locator("[data-testid=clock]").inner_text() == f"t = {at:.1f} s", 10, f"t = {at} s")
        assert state(page) == "ON_HOLD"
        page.screenshot(path=str(tmp_path / "replay.png"), full_page=True)
        # Play at the --realtime factor, 10 sim seconds a wall second, runs to the end of the run and stops there.
        assert page.locator("#speed").input_value() == "10"
        end = float(page.locator("[data-testid=slider]").get_attribute("max"))
        assert end > at + 2.0  # something is left to play
        started = time.monotonic()
        page.locator("#play").click()
        # The page plays by the wall clock: it reaches the end once (end - at) / 10 s have passed, however late its
        # timer fires; the wait is that with a margin for a busy machine.
        watch(page, lambda: float(page.locator("body").get_attribute("data-t")) >= end - 0.1, (end - at) / 10 + 15,
              "the replay's end")
        assert time.monotonic() - started >= (end - at) / 10 * 0.8  # paced, not a jump to the end
        watch(page, lambda: page.locator("#play").inner_text() == "Play", 5, "Play again at the end")
    finally:
        page.close()
        view.terminate()
        view.wait(timeout=10)


@contextlib.contextmanager
def elsewhere(tmp_path: Path) -> Iterator[str]:
    """The URL of a page served by another web server of this machine (another origin than the dashboard's)."""
    root = tmp_path / "elsewhere"
    root.mkdir()
    (root / "index.html").write_text("<p>another page of this machine</p>")
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(root))
    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler) as server:
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield f"http://127.0.0.1:{server.server_address[1]}/"
        finally:
            server.shutdown()
            thread.join(5)


def start_proxy(upstream: int, *rules: str) -> tuple[subprocess.Popen[str], int]:
    """`hils faults proxy` in front of a served controller; its port once it relays."""
    proc = subprocess.Popen([sys.executable, "-m", "hils", "faults", "proxy", "--upstream", f"127.0.0.1:{upstream}",
                             *rules], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20)
    match = re.match(r"proxying udp:127\.0\.0\.1:(\d+) ", proc.stdout.readline() if ready else "")
    if match is None:
        proc.kill()
        raise AssertionError(f"the proxy printed no address: {proc.stderr.read()}")
    return proc, int(match[1])


def panel_states(page: Page) -> dict[str, str]:
    return page.eval_on_selector_all("[data-intersection]", "els => Object.fromEntries(els.map(e => [e.dataset."
                                     "intersection, e.querySelector('[data-testid=manager-state]').innerText]))")


def test_corridor_page_has_a_panel_per_intersection_and_recovers_one(tmp_path: Path, browser: Browser) -> None:
    """The corridor's four controllers served by one `hils emulator serve --scenario corridor`, J2's link through a
    proxy that drops everything from 17 to 25 s: four panels west to east, each changing phases; J2 alone in
    TIMEOUT; its panel's Recover brings it back. Then the run replayed: four panels, the slider, J2's TIMEOUT."""
    served = start_emulator(tmp_path / "serve.log", "--scenario", "corridor", count=4)
    # The controllers change phases at about 6, 11 (yellow) and 16 s: J2's link drops after that.
    proxy, j2 = start_proxy(served.ports[1], "--drop", "17:25")
    ports = [served.ports[0], j2, *served.ports[2:]]
    run_dir = tmp_path / "run"
    page = browser.new_page(viewport={"width": 1280, "height": 760})
    proc = None
    try:
        proc, url = start_dashboard(sys.executable, str(Path(__file__).parent / "corridor_live_run.py"), str(run_dir),
                                    *(f"snmp://127.0.0.1:{port}?community=private&version=2c" for port in ports))
        page.goto(url)
        watch(page, lambda: page.locator("[data-intersection]").count() == 4, 15, "four panels")
        # West to east, one row: the map's order, whatever the order of the page's elements.
        boxes = {tls: page.locator(f"[data-intersection={tls}]").bounding_box() for tls in ("J1", "J2", "J3", "J4")}
        assert [b["x"] for b in boxes.values()] == sorted(b["x"] for b in boxes.values())
        assert len({b["y"] for b in boxes.values()}) == 1
        assert page.locator("#run").inner_text().startswith("corridor: four signalised intersections on an arterial · "
                                                            "wall-clock · switch")
        indications: dict[str, set[tuple[tuple[str, str], ...]]] = {tls: set() for tls in boxes}

        def every_panel_changed() -> bool:
            for tls, seen in indications.items():
                now = shown(page, f"[data-intersection={tls}] ")
                if "none" not in now.values():  # polled
                    seen.add(tuple(sorted(now.items())))
            return all(len(seen) > 1 for seen in indications.values())

        watch(page, every_panel_changed, 20, "the phases change on every panel")
        watch(page, lambda: panel_states(page)["J2"] == "TIMEOUT", 20, "J2 in TIMEOUT")
        states = panel_states(page)
        assert all(states[tls] != "TIMEOUT" for tls in ("J1", "J3", "J4")), states
        j2_panel = page.locator("[data-intersection=J2]")
        assert "communication" in j2_panel.locator("[data-testid=timeout-reason]").inner_text()
        assert j2_panel.locator("[data-testid=recover]").is_visible()
        assert page.locator("[data-intersection=J1] [data-testid=recover]").is_hidden()
        assert "TIMEOUT at J2" in page.locator("[data-testid=status]").inner_text()
        page.wait_for_timeout(1500)  # a cabinet read or two: the panels show calls and PhaseNext
        page.screenshot(path=str(tmp_path / "corridor.png"), full_page=True)

        def recovered() -> bool:
            # Recovery fails while the proxy still drops (until 25 s): ask again until the manager is back.
            if panel_states(page)["J2"] == "TIMEOUT" and j2_panel.locator("[data-testid=recover]").is_visible():
                j2_panel.locator("[data-testid=recover]").click()
                page.wait_for_timeout(1000)
            return panel_states(page)["J2"] in {"IDLE", "ON_HOLD"}

        watch(page, recovered, 20, "J2 back to IDLE after Recover")
        assert j2_panel.locator(".said").inner_text() == "requested"
        # Whose manager to recover must be said, and be one of the run's.
        for query in ("", "?intersection=J9"):
            status, err = get(page_root(url) + "api/recover" + query, "POST", secret_of(url))
            assert status == 400 and "allowed: J1, J2, J3, J4" in err["error"]
    finally:
        page.close()
        interrupt(proc)
        proxy.terminate()
        proxy.wait(timeout=10)
        served.stop()
    records = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    timeouts = [r for r in records if r["kind"] == "timeout_entered"]
    assert {r["intersection"] for r in timeouts} == {"J2"}
    assert any(r["kind"] == "recovered" and r["intersection"] == "J2" for r in records)

    # The same run replayed: four panels; at the TIMEOUT's instant J2's panel shows it, the others do not.
    view, url = start_view(str(run_dir))
    page = browser.new_page(viewport={"width": 1280, "height": 760})
    try:
        page.goto(url)
        watch(page, lambda: page.locator("[data-intersection] [data-phase]").count() == 32, 15, "four panels")
        at = timeouts[0]["t"] + 0.5
        page.locator("[data-testid=slider]").fill(str(at))
        watch(page, lambda: page.locator("[data-testid=clock]").inner_text() == f"t = {at:.1f} s", 10, f"t = {at}")
        states = panel_states(page)
        assert states["J2"] == "TIMEOUT" and all(states[tls] != "TIMEOUT" for tls in ("J1", "J3", "J4")), states
        page.screenshot(path=str(tmp_path / "corridor-replay.png"), full_page=True)
    finally:
        page.close()
        view.terminate()
        view.wait(timeout=10)


def test_the_page_shows_the_overlaps_and_a_flashing_yellow_arrow(tmp_path: Path, browser: Browser) -> None:
    """A virtual-time run of the city four-leg whose cabinet (overlap status too) is read every second, replayed
    with `hils view`: a row of the eight overlaps under the rings, each as the controller showed it, the flashing
    yellow arrows blinking beside their opposing through."""
    from hils.dashboard.cabinet import read_cabinet
    from hils.protocol.config import load
    from hils.run.testbed import Testbed
    from hils.sim.network import data_path

    path = data_path("four_leg_city.toml")
    config = load(path)

    def attach(tb: Testbed) -> None:
        tb.env.process(read_cabinet(tb.env, tb.transport, tb.events, config.groups,
                                    overlap_groups=config.overlap_groups))

    with Testbed(config, sumo=False, seed=1, duration=40.0, log_path=tmp_path / "events.jsonl",
                 on_reset=attach) as tb:
        tb.reset()
        tb.run()
    view, url = start_view(str(tmp_path), "--config", str(path))
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    try:
        page.goto(url)
        watch(page, lambda: page.locator("[data-overlap]").count() == 8, 15, "the overlaps")
        page.locator("[data-testid=slider]").fill("2")
        watch(page, lambda: page.locator("[data-testid=clock]").inner_text() == "t = 2.0 s", 10, "t = 2.0 s")
        overlaps = page.eval_on_selector_all("[data-overlap]", "els => Object.fromEntries(els.map(e => "
                                                               "[e.dataset.overlap, e.dataset.shown]))")
        # 2+6 green from start-up: their right turns (C, D) green, the west and east lefts (E, F) flashing.
        assert shown(page)["2"] == "G" and shown(page)["6"] == "G"
        assert overlaps == {"A": "r", "B": "r", "C": "G", "D": "G", "E": "F", "F": "F", "G": "r", "H": "r"}
        assert page.locator("[data-overlap=E]").get_attribute("title") == ("overlap E (fya, included 1, modifiers "
                                                                           "2): flashing yellow arrow")
        page.screenshot(path=str(tmp_path / "overlaps.png"), full_page=True)
    finally:
        page.close()
        view.terminate()
        view.wait(timeout=10)
