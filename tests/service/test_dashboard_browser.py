"""The dashboard in a real browser: Debian's chromium driven by playwright, on a real daemon fed
by a replayed KVH capture. Skipped without chromium or playwright, except under CI (CI set),
where it must run."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import (
    DetectorSettings,
    DeviceSettings,
    SchedulerSettings,
    Settings,
    SiteSettings,
)

TOKEN = "dashboard-test-token-0123456789"
REFUSED_401 = "the server responded with a status of 401 (Unauthorized)"


@pytest.fixture()
def daemon(tmp_path: Path, serve, replay) -> Iterator[tuple[str, Any]]:
    """A real daemon on a free port, its 24 windows stored and version 1 accepted."""
    rate = 100.0
    session = simulate_session(kvh_like_truth(4), "24", latitude_deg=50.0, seed=4, rate_hz=rate,
                               window_s=15.0, slew_s=3.0, first_hold_s=30.0)  # fmt: skip
    data = session_to_kvh(session, rng=4)[0]
    capture = tmp_path / "session.bin"
    capture.write_bytes(data)
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "coefficients.json"),
        device=DeviceSettings(url=f"replay://{capture}?speed=max&rate={rate:g}", rate_hz=rate),
        site=SiteSettings(latitude_deg=50.0),
        detector=DetectorSettings(init_still_s=20.0, min_duration_s=5.0),
        # manual jobs only (min_positions above the 24 windows), with the shipped method on 20
        # Monte Carlo runs (what the page shows needs no more; bench_mcs_slews times 100)
        scheduler=SchedulerSettings(min_positions=100, min_new_positions=100, mc_runs=20),
        api={"port": 0, "token": TOKEN},
    )
    with serve(settings) as (base, service):
        replay(service, len(data))
        with httpx.Client(base_url=base, timeout=30) as http:
            auth = {"Authorization": f"Bearer {TOKEN}"}
            assert http.post("/recalibrate", headers=auth).status_code == 202
            service.scheduler.wait(timeout=300)
            assert http.get("/coefficients").json()["version"] == 1
        # the job ran what the daemon ships ([scheduler] method), not a faster stand-in
        assert service.store.current().method.startswith(SchedulerSettings().method)
        yield base, service


@pytest.mark.slow
def test_dashboard_draws_updates_live_and_shows_refusals(daemon, page, tmp_path):
    from playwright.sync_api import expect

    base, service = daemon
    # two looks of the drift test at new windows, the second an alarm (as the scheduler emits)
    for k, stat in enumerate((3.2, 41.0)):
        service.events.emit("drift", f"look {k}", {
            "version": 1, "statistic": stat, "threshold": 17.0, "last_id": 25 + k,
            "alarm_window": k or None, "suspect": "gyro x scale, about +600 ppm"})  # fmt: skip
    problems: list[str] = []  # script errors and CSP violations (reported as console errors)
    page.on("pageerror", lambda exc: problems.append(str(exc)))
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
    page.goto(f"{base}/")

    # the current version: every coefficient of both triads, with status and sigma
    page.wait_for_selector("#coefficients tbody tr:not(.group)")
    assert page.text_content("#version") == "v1"
    assert page.text_content("#verdict") == "ACCEPTED"
    rows = page.locator("#coefficients tbody tr:not(.group)")
    assert rows.count() == 27
    assert "gyro Kx" in rows.first.text_content()
    assert "estimated" in rows.first.text_content()
    # the navigator's figures: the gyrocompass heading error now and before (the prior's)
    expect(page.locator("#nav-impact")).to_contain_text("gyrocompass heading error")
    expect(page.locator("#nav-impact")).to_contain_text("heading error before (no prior")
    # plotly drew the history (one accepted point) and the coverage (24 stored windows)
    page.wait_for_selector("#history-chart .main-svg")
    page.wait_for_selector("#coverage-chart .scatterlayer .point")
    assert page.locator("#history-chart .scatterlayer .point").count() >= 1
    window_points = page.locator("#coverage-chart .scatterlayer .trace").first.locator(".point")
    assert window_points.count() == 24
    page.wait_for_selector("#residual-chart .barlayer .point")
    # the drift statistic over time against its threshold, and why the last version ran
    page.wait_for_selector("#drift-chart .scatterlayer .point")
    assert page.locator("#drift-chart .scatterlayer .trace").first.locator(".point").count() == 2
    expect(page.locator("#drift-reason")).to_have_text("version 1 (accepted) ran because of manual")
    assert page.locator("#windows tbody tr").count() == 24
    # health and log are polled
    # (the replayed capture has ended, so the reader reports a silent device: degraded)
    status = httpx.get(f"{base}/health").json()["status"]
    expect(page.locator("#health")).to_have_text(f"health {status.upper()}")
    if status != "ok":
        expect(page.locator("#problems")).to_contain_text("reader:")
    page.wait_for_selector("#log tbody tr")
    expect(page.locator("#live")).to_have_text("live")

    # without a token the trigger is refused, and the page says so
    page.fill("#token", "")
    page.click("#recalibrate")
    page.wait_for_selector("#trigger-result.refused")
    assert "refused (401)" in page.text_content("#trigger-result")

    # with the token: queued, and the accepted version arrives without a reload
    page.evaluate("() => { window.__same_page = true; }")
    page.fill("#token", TOKEN)
    page.click("#recalibrate")
    page.wait_for_selector("#trigger-result.queued")
    expect(page.locator("#version")).to_have_text("v2", timeout=180_000)
    assert page.evaluate("() => window.__same_page") is True
    assert page.evaluate("() => sessionStorage.getItem('recal-token')") == TOKEN
    accepted_points = page.locator("#history-chart .scatterlayer .trace").nth(2).locator(".point")
    expect(accepted_points).to_have_count(2)
    assert "vs v1" in page.text_content("#coefficients thead")
    page.screenshot(path=str(tmp_path / "dashboard.png"), full_page=True)
    # the refusal itself is the only failed request
    assert problems == [f"Failed to load resource: {REFUSED_401}"], problems
