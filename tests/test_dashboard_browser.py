"""The dashboard's page in a real browser: Debian's chromium, headless, driven by playwright.

A wall-clock `hils run --dashboard` against `hils emulator serve`: the page shows the phases change
and the manager's state; the emulator is then stopped (SIGSTOP), the page shows TIMEOUT with its
reason, the emulator continues and the page's Recover button brings the manager back to IDLE. The
finished run is then replayed with `hils view`: the slider moves it, Play runs it at --realtime.
Screenshots are kept in the test's tmp dir (``live.png``, ``timeout.png``, ``replay.png``). Nothing
downloads a browser: chromium comes from the Makefile's deps target.
"""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page, sync_playwright
from test_dashboard import start_view

from harness.processes import start_emulator

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


def shown(page: Page) -> dict[str, str]:
    return page.eval_on_selector_all("[data-phase]", "els => Object.fromEntries(els.map(e => "
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


def test_live_page_shows_phases_change_timeout_and_recovery(tmp_path: Path, browser: Browser, paper_toml: str) -> None:
    # Decisions every 4 s instead of 10, so that phases change soon.
    config = tmp_path / "fast.toml"
    config.write_text(paper_toml.replace("control_interval = 10.0", "control_interval = 4.0"))
    served = start_emulator(tmp_path / "serve.log")
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "hils", "run", "--no-sumo", "--no-progress", "--config", str(config),
                             "--target", f"snmp://127.0.0.1:{served.port}?community=private&version=2c",
                             "--duration", "120", "--recover-after", "-1", "--dashboard", "0",
                             "--dashboard-control", "--out", str(run_dir)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30)
        line = proc.stdout.readline() if ready else ""
        match = re.match(r"dashboard: (http://127\.0\.0\.1:\d+/)", line)
        assert match, f"no dashboard URL: {line!r}"
        page.goto(match[1])
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
        page.locator("[data-testid=recover]").click()
        watch(page, lambda: state(page) in {"IDLE", "ON_HOLD"}, 20, "IDLE after Recover")
        assert page.locator("#recover-said").inner_text() == "requested"
    finally:
        page.close()
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
        served.stop()
    records = (run_dir / "events.jsonl").read_text()
    assert '"kind":"recovered"' in records and '"reason":"communication"' in records

    # The same run replayed: the slider moves the page to an instant of the run.
    view, url = start_view(str(run_dir), "--realtime", "10")
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    try:
        page.goto(url)
        watch(page, lambda: page.locator("[data-phase]").count() == 8, 15, "the phases")
        page.locator("[data-testid=slider]").fill("5")
        watch(page, lambda: page.locator("[data-testid=clock]").inner_text() == "t = 5.0 s", 10, "t = 5.0 s")
        assert state(page) in {"IDLE", "ON_HOLD"}
        page.screenshot(path=str(tmp_path / "replay.png"), full_page=True)
        # Play at the --realtime factor, 10 sim seconds a wall second, runs to the end of the run and stops there.
        assert page.locator("#speed").input_value() == "10"
        end = float(page.locator("[data-testid=slider]").get_attribute("max"))
        assert end > 7.0  # the slider was put at 5 s: something is left to play
        started = time.monotonic()
        page.locator("#play").click()
        watch(page, lambda: float(page.locator("body").get_attribute("data-t")) >= end - 0.1, 5, "the replay's end")
        assert time.monotonic() - started >= (end - 5.0) / 10 * 0.8  # paced, not a jump to the end
        watch(page, lambda: page.locator("#play").inner_text() == "Play", 5, "Play again at the end")
    finally:
        page.close()
        view.terminate()
        view.wait(timeout=10)
