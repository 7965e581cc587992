"""The "time to fail" table of ``make bench``: decks that cannot converge against their healthy
counterparts, whole ``poise solve`` processes (start-up, solve, results file written).

A failing deck must cost little more than the healthy one (ratio <= 3) and, under 100 bodies,
at most 2 s; it must still say why (status ``no_equilibrium`` or ``diverged`` with the body
named, never the generic "try MKEAM"), exit 1 and write the results file. The pairs: a
pendulum whose torque exceeds m g l, a slide at 45 degrees with nothing holding the body
along it (also on a cylindrical joint with the mass off its axis), a rack sliding down and
turning a free pinion, a slider-crank whose crank torque no slider load position can balance, decks with a
joint, gear or coupler removed or a bushing re-routed (the mutations the fuzzer makes), and
hanging chains of 200 and 1000 links with two pins removed (``poise.gen.chain``). Each pair
runs round-robin after one warm-up run each (``benchmarks.chain._walls``).
``python -m benchmarks --only failfast`` runs this table alone.
"""
from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np

from benchmarks.chain import _poise_cmd, _user_env, _walls

RATIO = 3.0
SMALL_S = 2.0            # a failing deck under SMALL_BODIES bodies fails within this
SMALL_BODIES = 100
G = 9.81                 # N/kg


def _pendulum(frac: float) -> str:
    from poise.gen.torque import torque_pendulum
    return torque_pendulum(frac).text()


def _slide(spring: bool, joint: str = "TRANSLATIONAL", arm: float = 0.0) -> str:
    """A 1 kg body on a joint inclined at 45 degrees under gravity (6.9 N along the slide),
    ``arm`` mm off its axis, held along it by a spring or by nothing (``poise.gen.slide``)."""
    from poise.gen.slide import slide
    extra = (lambda d: d.spring(1, 20, 102, 1.0, 0.0)) if spring else None
    return slide(45.0, joint=joint, arm=arm, extra=extra).text()


def _rack(spring: float) -> str:
    """A rack on a 30 degree slide turning its pinion, held by a torsion spring on the pinion
    or by nothing."""
    from poise.gen.slide import rack_and_pinion
    return rack_and_pinion(30.0, spring=spring).text()


def _delete(text: str, tag: str, id_: int) -> str:
    out, n = re.subn(rf'\s*<{tag} id="{id_}"[^>]*/>', "", text, flags=re.S)
    if n != 1:
        raise ValueError(f"{tag} id={id_} not found")
    return out


def _reroute(text: str, tag: str, id_: int, attr: str, value) -> str:
    def sub(m):
        return re.sub(rf'\b{attr}="[^"]*"', f'{attr}="{value}"', m.group(0))
    out, n = re.subn(rf'<{tag} id="{id_}"[^>]*/>', sub, text, flags=re.S)
    if n != 1:
        raise ValueError(f"{tag} id={id_} not found")
    return out


def _crank_torque(root: Path, torque: float) -> str:
    """``decks/slider_crank_load.xml`` with its crank spring replaced by a constant crank
    torque [N mm]: the 60 N slider load balances at most 60 x 105 mm."""
    text = (root / "decks" / "slider_crank_load.xml").read_text()
    return re.sub(r'<Force_SpringDamper id="1".*?/>',
                  '<Force_Vector_OneBody id="2" label="Crank torque" type="TORQUEONLY" '
                  'marker_id="200" ref_marker_id="100" fx_expression="0." fy_expression="0." '
                  f'fz_expression="0." tx_expression="0." ty_expression="0." '
                  f'tz_expression="{torque!r}"/>', text, flags=re.S)


def _chain(n: int, pins_removed: bool) -> str:
    from poise.gen.chain import build_chain_deck
    text = build_chain_deck(n)
    if pins_removed:            # the pins at a third and two thirds: the middle third falls
        for j in (n // 3 + 1, 2 * n // 3 + 1):
            text = _delete(text, "Constraint_Joint", j)
    return text


def pairs(root: Path, quick: bool = False) -> list[tuple[str, int, str, str]]:
    """``(name, bodies, failing deck text, healthy deck text)``."""
    decks = root / "decks"
    read = lambda name: (decks / name).read_text()   # noqa: E731
    out = [
        ("pendulum, torque 1.5 m g l (healthy: 0.5 m g l)", 1, _pendulum(1.5), _pendulum(0.5)),
        ("slide at 45 deg, nothing along it (healthy: a spring)", 1, _slide(False),
         _slide(True)),
        ("cylindrical joint at 45 deg, mass 600 mm off its axis (healthy: a spring)", 1,
         _slide(False, "CYLINDRICAL", 600.0), _slide(True, "CYLINDRICAL", 600.0)),
        ("rack at 30 deg turning a free pinion (healthy: a torsion spring)", 2, _rack(0.0),
         _rack(500.0)),
        ("slider-crank, crank torque 10 N m (healthy: 3 N m)", 3,
         _crank_torque(root, 10000.0), _crank_torque(root, 3000.0)),
        ("double_pendulum, elbow joint removed", 2,
         _delete(read("double_pendulum.xml"), "Constraint_Joint", 2), read("double_pendulum.xml")),
        ("elem_gear_rack, gear removed", 2, _delete(read("elem_gear_rack.xml"),
                                                   "Constraint_Gear", 1),
         read("elem_gear_rack.xml")),
        ("elem_coupler, coupler removed", 2, _delete(read("elem_coupler.xml"),
                                                    "Constraint_Coupler", 1),
         read("elem_coupler.xml")),
        ("bushing_block, bushing re-routed to its own body", 1,
         _reroute(read("bushing_block.xml"), "Force_Bushing", 1, "j_marker_id", 202),
         read("bushing_block.xml")),
        ("200-link chain, two pins removed", 200, _chain(200, True), _chain(200, False)),
    ]
    if not quick:
        out.append(("1000-link chain, two pins removed", 1000, _chain(1000, True),
                    _chain(1000, False)))
    return out


def _solve_cmd(deck: Path) -> list[str]:
    return _poise_cmd() + ["solve", str(deck), "-o", str(deck.with_suffix(".h5")), "-q"]


def _outcome(deck: Path, out: Path) -> dict:
    """One ``poise solve --json`` of the failing deck: exit code, status, message, file."""
    if out.exists():
        out.unlink()
    r = subprocess.run(_poise_cmd() + ["solve", str(deck), "-o", str(out), "--json", "-q"],
                       capture_output=True, text=True, env=_user_env())
    try:
        a = json.loads(r.stdout)["analyses"][0]
        status, message = a["status"], a["message"]
    except (ValueError, KeyError, IndexError):
        status, message = "?", r.stderr.strip()[-300:]
    import h5py
    frame = ""
    if out.exists():
        with h5py.File(out, "r") as f:
            frame = str(np.asarray(f["analysis_000/frames/status"]).astype(str)[0])
    return dict(exit=r.returncode, written=out.exists(), frame_status=frame, status=status,
                message=message)


def run(tmp: Path, log=print, quick=False, repeat: int | None = None):
    """Returns (rows, markdown lines, targets)."""
    root = Path(__file__).resolve().parents[1]
    repeat = (1 if quick else 3) if repeat is None else repeat
    rows = []
    for k, (name, nb, bad, good) in enumerate(pairs(root, quick)):
        pb, pg = tmp / f"failfast_{k}_fail.xml", tmp / f"failfast_{k}_ok.xml"
        pb.write_text(bad)
        pg.write_text(good)
        w = _walls({"fail": _solve_cmd(pb), "ok": _solve_cmd(pg)}, repeat)
        (st_f, _), (st_g, rc_g) = w["fail"], w["ok"]
        o = _outcome(pb, tmp / f"failfast_{k}_fail_json.h5")
        tf, tg = st_f["median"], st_g["median"]
        row = dict(bench="failfast", name=name, bodies=nb, fail_s=st_f, healthy_s=st_g,
                   ratio=tf / tg, healthy_exit=rc_g, **o)
        rows.append(row)
        log(f"[failfast] {name}: {tf:.2f} s / {tg:.2f} s = {tf / tg:.2f}x, exit {o['exit']}, "
            f"{o['frame_status']}: {o['message'][:120]}")
    return rows, markdown(rows), targets(rows)


def _precise(r) -> bool:
    """The failure says why: exit 1, the results file written, a frame status that names the
    reason (not the budget) and no generic advice."""
    return (r["exit"] == 1 and r["written"] and r["frame_status"] in ("no_equilibrium", "diverged")
            and "try MKEAM" not in r["message"])


def targets(rows) -> list[tuple[str, str, str, bool]]:
    small = [r for r in rows if r["bodies"] < SMALL_BODIES]
    worst = max(rows, key=lambda r: r["ratio"]) if rows else None
    tg = []
    if worst:
        tg.append(("time to fail / time to converge, every pair (whole process)",
                   f"<= {RATIO:g}x", f"worst {worst['ratio']:.2f}x ({worst['name']})",
                   all(r["ratio"] <= RATIO for r in rows)))
    if small:
        w = max(small, key=lambda r: r["fail_s"]["median"])
        tg.append((f"time to fail, decks under {SMALL_BODIES} bodies", f"<= {SMALL_S:g} s",
                   f"worst {w['fail_s']['median']:.2f} s ({w['name']})",
                   all(r["fail_s"]["median"] <= SMALL_S for r in small)))
    tg.append(("every failing deck exits 1, writes its results and says why",
               "all", f"{sum(map(_precise, rows))}/{len(rows)}", all(map(_precise, rows))))
    tg.append(("every healthy deck converges (exit 0)", "all",
               f"{sum(r['healthy_exit'] == 0 for r in rows)}/{len(rows)}",
               all(r["healthy_exit"] == 0 for r in rows)))
    return tg


def markdown(rows) -> list[str]:
    md = ["## Time to fail", "",
          "Decks that cannot converge against their healthy counterparts: `poise solve DECK -o "
          "OUT -q`, whole process (start-up, solve, results file), median of the runs "
          "(round-robin after a warm-up each). The failing deck's frame status and the "
          "beginning of its message show the reason it gives.", "",
          "| failing deck (healthy counterpart) | bodies | fail [s] | healthy [s] | ratio | "
          "exit | status | reason |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        why = r["message"].split("; ")
        why = next((p for p in why if "free to" in p or "within reach" in p), why[0])
        why = re.sub(r"\S+\.xml:\d+: ", "", why)[:110].replace("|", "/")
        md.append(f"| {r['name']} | {r['bodies']} | {r['fail_s']['median']:.2f} | "
                  f"{r['healthy_s']['median']:.2f} | {r['ratio']:.2f} | {r['exit']} | "
                  f"{r['frame_status']} | {why}… |")
    md += ["", "| target | limit | measured | result |", "|---|---|---|---|"]
    for name, lim, meas, ok in targets(rows):
        md.append(f"| {name} | {lim} | {meas} | {'PASS' if ok else 'MISS'} |")
    md.append("")
    return md
