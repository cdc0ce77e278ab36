"""`recal demo --vessel`: the whole product on a hull-fixed FOG at berth (recal.sim.vessel), read
with ``[detector] motion = "hull"`` and published under ``[gate] publish_observable_part``."""

import json
import re

from service.cli.main import main


def test_demo_vessel_runs_the_hull_fixed_product(tmp_path, capsys):
    folder = tmp_path / "demo"
    assert main(["demo", "--vessel", "--dir", str(folder), "--seed", "1"]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "hull-fixed FOG at berth" in captured.err
    # one quasi-static window per hold, none overlapping a turn
    m = re.search(r"windows: (\d+) stored .*, (\d+) overlapping a turn", out)
    assert m is not None, out
    assert int(m.group(1)) == 12 and int(m.group(2)) == 0, out
    published = json.loads((folder / "coefficients.json").read_text())
    assert published["version"] >= 1 and published["held"], published.keys()
    assert "gyro.scale.Kz" in published["held"]  # a heading-only design cannot see it
    # every printed error / sigma of the accepted version, estimated or held, is within 3.5
    rows = [line.split()[1:] for line in out.splitlines()
            if line.startswith(("  gyro.", "  accel."))]  # fmt: skip
    assert len(rows) == 4 and all(len(r) == 3 for r in rows), out
    cells = [c for r in rows for c in r]
    zs = [float(c.rstrip("h")) for c in cells]
    assert max(abs(z) for z in zs) < 3.5, out
    assert any(not c.endswith("h") for c in cells)  # something was estimated
    assert "navigation: gyrocompass heading error" in out
    for name in ("truth.json", "prior.json", "session.bin", "ship.nmea"):
        assert (folder / name).is_file()
    # the ship's own sensors ([nav] log beside the replayed capture): every window stored at the
    # GNSS latitude, its heading creep measured from the gyrocompass (its vertical rate kept)
    from service.store import Store

    store = Store(f"sqlite:///{folder / 'recal.db'}")
    try:
        positions, _ = store.positions()
    finally:
        store.close()
    cols = positions.columns
    assert abs(cols["latitude_deg"] - 57.7).max() < 1e-4, cols["latitude_deg"]
    assert (cols["sog_kn"] < 0.05).all() and "creep_dph" in cols
    assert "gyro_vertical" not in cols or (cols["gyro_vertical"] != 0).all()
