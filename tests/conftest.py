"""Shared fixtures: where ../shared/data lives and how tests treat its absence; a real browser;
throwaway PostgreSQL databases.

PostgreSQL comes from RECAL_TEST_POSTGRES (default: the local trust-auth server's ``test``
database); each test session creates its own ``recal_test_<random>`` database and drops it at
the end. Unreachable PostgreSQL skips those tests, except under CI, where it fails them.
"""

from __future__ import annotations

import os
import secrets
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import psycopg
import pytest
from psycopg import sql
from sqlalchemy.engine import make_url
from threadpoolctl import threadpool_limits

# One BLAS thread per test process: the suite runs on as many pytest workers as the machine
# has cores (README: pytest -n 2 on 2 cores), and OpenBLAS's own threads on top of that thrash
# (measured: a wander fit 0.87 s with one thread, 7.0 s with two under the suite's load). The
# environment reaches the daemons and CLIs tests start as subprocesses; threadpoolctl covers
# this process, where numpy may already be loaded. The engine's own pools set 1 themselves.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
threadpool_limits(1, user_api="blas")
# The suite starts its own CLIs and daemons a few hundred times. Where PYTHONDONTWRITEBYTECODE
# is set (this project's machines set it), each of them compiled the project's modules from
# source again, about 0.15 s a process, and each worker rewrote every test module's asserts:
# bytecode is cached for this session and the processes it starts (*.pyc is ignored by git).
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = PROJECT_ROOT.parent / "shared" / "data"
# The source tree's test tools (benchmarks/fault_proxy.py, ...) are importable as the benchmark
# scripts import them: they are not part of the installed package (tests/test_wheel.py)
sys.path.insert(0, str(PROJECT_ROOT / "benchmarks"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data; skipped only when absent outside CI (under CI its absence fails)."""
    if not SHARED_DATA.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"shared data folder {SHARED_DATA} is missing under CI")
        pytest.skip(f"shared data folder {SHARED_DATA} not present")
    return SHARED_DATA


@pytest.fixture(scope="session", autouse=True)
def state_directory(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The state folder of every daemon a test starts without its own paths: a session folder
    (STATE_DIRECTORY, as systemd sets it), never the user's ~/.local/state/recal nor the working
    folder (service.config.default_state_dir). Subprocesses inherit it."""
    folder = tmp_path_factory.mktemp("state") / "recal"
    patch = pytest.MonkeyPatch()
    patch.setenv("STATE_DIRECTORY", str(folder))
    try:
        yield folder
    finally:
        patch.undo()


def pytest_configure(config: pytest.Config) -> None:
    """Hypothesis keeps its example database and constants cache in the system's temporary
    folder, not in ``.hypothesis/`` of the working folder: a test run leaves no file there. Set
    here, before the test modules are collected (the cache is written while they are)."""
    from hypothesis.configuration import set_hypothesis_home_dir

    set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "recal-tests-hypothesis")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests marked slow run first (a stable sort: the rest keep their order). Under xdist the
    longest jobs start while every worker is free, and the short ones fill in at the end, instead
    of one long test running alone after the others have finished."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


CHROMIUM = Path("/usr/bin/chromium")


def browser_missing() -> str | None:
    """Why the browser tests cannot run here (None: they can)."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed"
    return None if CHROMIUM.exists() else f"{CHROMIUM} is missing (apt-get install chromium)"


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """Debian's chromium driven by playwright; skipped without them, except under CI (CI set),
    where they must be there (.ci/run installs chromium)."""
    missing = browser_missing()
    if missing and not os.environ.get("CI"):
        pytest.skip(missing)
    assert missing is None, f"the browser tests must run under CI: {missing}"
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        try:
            yield b
        finally:
            b.close()


@pytest.fixture()
def page(browser: Any) -> Iterator[Any]:
    """A 1600 x 1000 page of :func:`browser`, closed after the test (which also ends a
    dashboard's /events stream before its daemon stops)."""
    page = browser.new_page(viewport={"width": 1600, "height": 1000})
    try:
        yield page
    finally:
        page.close()


# ---- PostgreSQL (tests/service, tests/fleet) -------------------------------------------

PG_ADMIN_URL = os.environ.get("RECAL_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/test")


def _admin() -> psycopg.Connection:
    return psycopg.connect(PG_ADMIN_URL, autocommit=True, connect_timeout=3)


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    """SQLAlchemy URL of a fresh database, dropped after the session."""
    try:
        admin = _admin()
    except psycopg.OperationalError as exc:
        reason = f"PostgreSQL at {PG_ADMIN_URL} unreachable: {str(exc).splitlines()[0]}"
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    name = f"recal_test_{secrets.token_hex(4)}"
    with admin:
        admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
    url = make_url(PG_ADMIN_URL).set(drivername="postgresql+psycopg", database=name)
    try:
        yield url.render_as_string(hide_password=False)
    finally:
        with _admin() as admin:
            admin.execute(sql.SQL("DROP DATABASE {} WITH (FORCE)").format(sql.Identifier(name)))


@pytest.fixture
def pg_database() -> Iterator[tuple[str, str]]:
    """(name, SQLAlchemy URL) of a fresh PostgreSQL database for one test, dropped after it;
    ``block_database`` can close it to connections (a database outage)."""
    try:
        admin = _admin()
    except psycopg.OperationalError as exc:
        if os.environ.get("CI"):
            pytest.fail(f"PostgreSQL unreachable: {exc}")
        pytest.skip(f"PostgreSQL unreachable: {exc}")
    name = f"recal_outage_{secrets.token_hex(4)}"
    with admin:
        admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
    url = make_url(PG_ADMIN_URL).set(drivername="postgresql+psycopg", database=name)
    try:
        yield name, url.render_as_string(hide_password=False)
    finally:
        with _admin() as admin:
            admin.execute(
                sql.SQL("ALTER DATABASE {} ALLOW_CONNECTIONS true").format(sql.Identifier(name))
            )
            admin.execute(sql.SQL("DROP DATABASE {} WITH (FORCE)").format(sql.Identifier(name)))


def _block_database(name: str, allow: bool) -> None:
    """Close database ``name`` to connections (ending its sessions), or open it again."""
    with _admin() as admin:
        admin.execute(
            sql.SQL("ALTER DATABASE {} ALLOW_CONNECTIONS {}").format(
                sql.Identifier(name), sql.SQL("true" if allow else "false")
            )
        )
        if not allow:
            admin.execute(
                "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = %s",
                (name,),
            )


@pytest.fixture
def block_database() -> Callable[[str, bool], None]:
    return _block_database
