"""``recal fleet reanalyse`` on Dask (issue 37, item 4): the workbench across the fleet on a local
cluster and on a separate ``dask scheduler`` with two ``dask worker`` processes, the verdicts,
and the dashboard's re-analysis page.

The fleets are benchmarks/bench_fleet_reanalyse.py's (simulated windows through the shore's
real ingest path); its 50-unit acceptance (>= 27 of 30 carriers, <= 1 of 20 others) runs there,
these use a few units with the same effect, and fail when a carrier is missed, a clean unit
called, or the verdict wrong."""

from __future__ import annotations

import importlib.util
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from service.cli.main import main
from service.fleet.reanalysis import reanalyse
from service.fleet.workbench import homogeneity, verdict

PROJECT = Path(__file__).resolve().parents[2]
ADMIN = "admin-token-0123456789abcdef"
EFFECT = "gyro.g_sensitivity"

pytest.importorskip("distributed")


def _bench():
    spec = importlib.util.spec_from_file_location(
        "bench_fleet_reanalyse", PROJECT / "benchmarks" / "bench_fleet_reanalyse.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_fleet_reanalyse"] = module
    spec.loader.exec_module(module)
    return module


def _config(tmp_path: Path, url: str) -> str:
    path = tmp_path / "shore.toml"
    path.write_text(f'database_url = "{url}"\n\n[api]\ntoken = "{ADMIN}"\n')
    return str(path)


def _hits(report: dict, carrying: set[str]) -> tuple[int, int]:
    found = {u["unit"]: u["refit"]["effects"][EFFECT]["significant"] for u in report["units"]}
    return sum(found[u] for u in carrying), sum(v for u, v in found.items() if u not in carrying)


@pytest.mark.slow
def test_effects_on_a_local_cluster_of_two_workers(tmp_path, capsys) -> None:
    bench = _bench()
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    carrying = bench.fill(url, units=6, carriers=4, windows=24, versions=False)
    config = _config(tmp_path, url)
    args = ["fleet", "reanalyse", "--config", config, "--workers", "2", "--windows", "24",
            "--effects", f"+{EFFECT}", "--json"]  # fmt: skip
    assert main(args) == 0
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert report["workers"] == 2 and report["scheduler"] is None
    assert _hits(report, carrying) == (4, 0), [u["refit"] for u in report["units"]]
    v = report["refit"]["models"][bench.MODEL][EFFECT]
    assert (v["verdict"], v["tested"], v["significant"]) == ("systematic", 6, 4)
    same = v["homogeneity"]  # one common value: the planted one, within its 1-sigma (4x)
    for (name, value), truth in zip(same["value"].items(), bench.G_SENSITIVITY, strict=True):
        assert abs(value - truth) < 4 * same["sigma"][name] + 2e-3, (name, value, truth)
    for u in report["units"]:
        r, fit = u["refit"], u["refit"]["effects"][EFFECT]
        assert r["error"] is None and r["windows"] == 24
        if u["unit"] in carrying:  # the effect removes the misfit
            assert r["chi2_red_before"] > 5 and fit["chi2_red_after"] < 2
        assert set(fit["estimate"]) == set(fit["sigma"]) and len(fit["estimate"]) == 9
    assert "re-analysed 6 units on 2 process(es)" in err and f"{EFFECT} systematic" in err
    # the dashboard's file, beside the config
    assert json.loads((tmp_path / "shore.reanalysis.json").read_text()) == report


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster(tmp_path) -> Iterator[str]:
    """A ``dask scheduler`` and two ``dask worker`` processes (one thread each) on free ports
    of 127.0.0.1; all stopped after the test, whatever happened."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(PROJECT)}
    dask = [sys.executable, "-m", "dask"]
    procs: list[subprocess.Popen] = []
    log = open(tmp_path / "dask.log", "wb")  # noqa: SIM115 - closed in the finally
    try:
        procs.append(subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port",
                                       str(port), "--no-dashboard"], env=env, cwd=tmp_path,
                                      stdout=log, stderr=subprocess.STDOUT))  # fmt: skip
        for i in range(2):
            procs.append(subprocess.Popen([*dask, "worker", address, "--nworkers", "1",
                                           "--nthreads", "1", "--no-dashboard", "--name",
                                           f"w{i}", "--host", "127.0.0.1"], env=env,
                                          cwd=tmp_path, stdout=log,
                                          stderr=subprocess.STDOUT))  # fmt: skip
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        # the workers first, while their scheduler still answers (stopped together, a worker
        # spent seconds on a scheduler that was going away), then the scheduler
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
        log.close()


@pytest.mark.slow
def test_effects_on_a_separate_scheduler_with_two_workers(tmp_path, dask_cluster) -> None:
    bench = _bench()
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    carrying = bench.fill(url, units=4, carriers=3, windows=24, versions=False, seed=1)
    started = time.perf_counter()
    report = reanalyse(url, scheduler=dask_cluster, effects=[EFFECT], windows=24)
    assert time.perf_counter() - started < 120
    assert report["scheduler"] == dask_cluster and report["workers"] == 2
    assert _hits(report, carrying) == (3, 0)
    assert report["refit"]["models"][bench.MODEL][EFFECT]["verdict"] == "systematic"


def test_a_plugin_is_tried_in_this_process_and_a_bad_scheduler_is_one_line(
    tmp_path, capsys, monkeypatch
) -> None:
    from service.fleet import reanalysis

    monkeypatch.setattr(reanalysis, "CONNECT_TIMEOUT_S", 2)  # nothing listens: no 20 s wait
    bench = _bench()
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    bench.fill(url, units=2, carriers=0, windows=12, versions=True)
    config = _config(tmp_path, url)
    plugin = str(PROJECT / "docs" / "examples" / "faraday_plugin.py")
    assert main(["fleet", "reanalyse", "--config", config, "--workers", "1",
                 "--plugin", plugin]) == 0  # fmt: skip
    out, err = capsys.readouterr()
    assert "gyro.faraday: chi2_red" in out and "model KVH-1750: gyro.faraday absent" in out
    report = json.loads((tmp_path / "shore.reanalysis.json").read_text())
    assert report["refit"]["effects"] == ["gyro.faraday"]
    assert all(u["drift"] is not None and u["windows"] == 12 for u in report["units"])
    assert main(["fleet", "reanalyse", "--config", config, "--effects", "+no.such"]) == 2
    assert "unknown effect(s) no.such" in capsys.readouterr().err
    bad = f"tcp://127.0.0.1:{_free_port()}"
    assert main(["fleet", "reanalyse", "--config", config, "--scheduler", bad,
                 "--effects", f"+{EFFECT}"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"cannot reach the Dask scheduler {bad}" in err


def test_verdicts_systematic_local_absent() -> None:
    def unit(sig: bool, x: float, s: float = 0.01) -> dict:
        fit = {"significant": sig, "estimate": {"a": x, "b": -x},
               "covariance": [[s * s, 0.0], [0.0, s * s]]}  # fmt: skip
        return {"error": None, "effects": {"e": fit}}

    same = [unit(True, 0.1 + 0.005 * (-1) ** i) for i in range(6)] + [unit(False, 0.0)] * 4
    assert verdict(same, "e")["verdict"] == "systematic"
    spread = [unit(True, 0.1 * i) for i in range(1, 7)] + [unit(False, 0.0)] * 4
    v = verdict(spread, "e")
    assert v["verdict"] == "local" and v["homogeneity"]["p_value"] < 0.01  # many, not one value
    few = [unit(True, 0.1)] * 3 + [unit(False, 0.0)] * 17
    assert verdict(few, "e")["verdict"] == "local"  # 3 of 20: more than 1 % false alarms give
    one = [unit(True, 0.1)] + [unit(False, 0.0)] * 19
    assert verdict(one, "e")["verdict"] == "absent"  # 1 of 20: what chance gives
    h = homogeneity([{"a": 1.0}, {"a": 3.0}], [[[1.0]], [[1.0]]])
    assert h["value"] == {"a": 2.0} and h["chi2"] == 2.0 and h["dof"] == 1


def test_the_dashboard_page_serves_the_newest_reanalysis_to_the_administrator(tmp_path) -> None:
    from fastapi.testclient import TestClient

    from service.fleet.api import create_app
    from service.fleet.config import ShoreApiSettings
    from service.fleet.store import FleetStore

    store = FleetStore(f"sqlite:///{tmp_path / 'fleet.db'}")
    store.create_schema()
    token = store.add_unit("SN-1", "M")
    app = create_app(store, ShoreApiSettings(token=ADMIN))
    app.state.reanalysis_path = tmp_path / "shore.reanalysis.json"
    admin = {"Authorization": f"Bearer {ADMIN}"}
    with TestClient(app) as client:
        page = client.get("/fleet/dashboard/reanalysis")
        assert page.status_code == 200 and "reanalysis.js" in page.text
        assert client.get("/fleet/dashboard/reanalysis.js").status_code == 200
        assert client.get("/fleet/dashboard/reanalysis.json", headers=admin).status_code == 404
        app.state.reanalysis_path.write_text('{"units": []}')
        assert client.get("/fleet/dashboard/reanalysis.json", headers=admin).json() == {"units": []}
        unit = {"Authorization": f"Bearer {token}"}
        assert client.get("/fleet/dashboard/reanalysis.json", headers=unit).status_code == 401
        assert client.get("/fleet/dashboard/reanalysis.json").status_code == 401
    store.close()
