"""docs/apply.md cannot drift from the code: its worked example's numbers are what
``recal.apply`` gives, and its reference implementation agrees with ``recal.apply`` on a
calibration with every catalogue effect."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

import recal
from recal.model.published import EQUATIONS

DOC = (Path(__file__).resolve().parents[2] / "docs" / "apply.md").read_text(encoding="utf-8")


def _worked_example() -> list[dict]:
    section = DOC.split("## Worked example", 1)[1].split("## Reference implementation", 1)[0]
    return [json.loads(b) for b in re.findall(r"```json\n(.*?)```", section, re.S)]


def _reference() -> dict:
    code = re.search(r"^## Reference implementation\n.*?```python\n(.*?)```", DOC, re.S | re.M)
    assert code
    namespace: dict = {}
    exec(code.group(1), namespace)  # the page's code, as a reader would paste it
    return namespace


def test_the_worked_example_is_what_recal_apply_gives() -> None:
    coeffs, sample, accel, gyro = _worked_example()
    out = recal.apply(coeffs, np.array([sample["gyro_out"]]), np.array([sample["accel_out"]]),
                      np.array([sample["temperature_c"]]))  # fmt: skip
    assert np.allclose(out.accel[0], accel["accel_g"], rtol=1e-12, atol=0)
    assert np.allclose(out.gyro[0], gyro["gyro_deg_h"], rtol=1e-12, atol=0)
    ref = _reference()["calibrate"]
    w, f = ref(coeffs, np.array([sample["gyro_out"]]), np.array([sample["accel_out"]]),
               np.array([sample["temperature_c"]]))  # fmt: skip
    assert np.allclose(f[0], accel["accel_g"], rtol=1e-12, atol=0)
    assert np.allclose(w[0], gyro["gyro_deg_h"], rtol=1e-12, atol=0)


def test_the_reference_implementation_agrees_with_recal_apply() -> None:
    from recal.model.apply import TEMPERATURE_RATE_SPAN_S

    ref = _reference()
    rng = np.random.default_rng(3)
    cs = recal.CoefficientSet.seed_truth()
    cat = recal.catalogue_terms()
    for name, term in cat.items():  # every catalogue effect, at a few times its typical size
        cs.values[name] = 3 * np.asarray(term.typical) * rng.choice([-1, 1], term.size)
    n = 4000
    t = np.arange(n) / 20.0
    gyro = 645 * (1e4 * rng.standard_normal((n, 3)) + 15)
    accel = 1.5 * rng.standard_normal((n, 3))
    temp = 22 + 0.01 * t
    out = recal.apply(cs, gyro, accel, temp, time_s=t)
    # the page's dT/dt and t, as it defines them
    first = np.searchsorted(t, t - TEMPERATURE_RATE_SPAN_S)
    span = t - t[first]
    dTdt = np.where(span > 0, (temp - temp[first]) / np.where(span > 0, span, 1) * 3600, 0.0)
    doc = cs.to_json_dict(cat)
    w, f = ref["calibrate"](doc, gyro, accel, temp, dTdt, (t - t[0]) / 3600)
    assert set(ref["PARAMS"]) == set(cat)  # the page knows every catalogue effect
    assert np.max(np.abs(f - out.accel) / np.linalg.norm(out.accel, axis=1)[:, None]) < 1e-12
    assert np.max(np.abs(w - out.gyro) / np.linalg.norm(out.gyro, axis=1)[:, None]) < 1e-12


def test_the_page_states_the_published_equations() -> None:
    """The equations the published file carries are those on the page (spaces aside)."""
    flat = " ".join(DOC.split())
    for key in ("misalignment",):
        assert EQUATIONS[key].replace(" ", "") in flat.replace(" ", "")
    for sensor in ("gyro", "accel"):
        assert " ".join(EQUATIONS[sensor].split()) in flat, sensor
