"""The words of the reproduce report: definitions, comparisons and report.md.

Every number in a sentence here comes from the runs (their summaries and trajectories, gathered
in the report), from the scenario they ran, or from the paper (the ``PAPER_*`` constants of
:mod:`sumo_swarm.study.reproduce_rows`); none is written in as text.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sumo_swarm.config import Scenario
from sumo_swarm.sim import metrics
from sumo_swarm.sim.scene import build_scene
from sumo_swarm.study.batch.store import INFLUENCE_THRESHOLD_PCT
from sumo_swarm.study.plots import FIGURES, lane_name
from sumo_swarm.study.reproduce_rows import (
    BASELINE,
    FOCUS,
    PAPER_BEHAVING_INTERVAL_S,
    PAPER_BEHAVING_STEPS,
    PAPER_CACC_SPEED_MPS,
    PAPER_CELL_LENGTH_M,
    PAPER_DESIRED_GAP_M,
    PAPER_GAIN_PCT,
    PAPER_GAP_EXCESS_PCT,
    PAPER_GAP_MEAN_M,
    PAPER_INFLUENCED,
    PAPER_PASS_S,
    PAPER_REGROUP_S,
    PAPER_SPEED_MPS,
    PAPER_UPSTREAM_REDUCTION_PCT,
    per_lane,
)

CAPPED = "swarm-capped"  # the swarm with its CAVs capped at the cruising speed
SURGE_MIN_MPS = 0.01  # a rise above the start speed smaller than this is not called a surge


def fmt(value: Any, digits: int = 2) -> str:
    """A number for a reader: booleans as yes/no, None as a dash, no "-0.00"."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if abs(value) < 0.5 * 10.0**-digits:
            value = 0.0
        return f"{value:.{digits}f}"
    return str(value)


def _blocked_hvs(scenario: Scenario) -> list[tuple[int, str]]:
    """(lane, id) of the HVs beside the platoon at the start (role "adjacent"), left first."""
    vehicles = build_scene(scenario).vehicles
    return sorted(((v.lane, v.id) for v in vehicles if v.role == "adjacent"), reverse=True)


def definitions(
    scenario: Scenario, compared_lane: int, n_lanes: int, paired_from_s: float | None = None
) -> dict[str, str]:
    """Each measure's definition, stated once (rows point to these by key).

    ``paired_from_s``: where the paired upstream window starts (the swarm run's decision) [s].
    """
    ev, sim = scenario.evaluation, scenario.simulation
    interval = scenario.planner.behaving_interval_s
    blocked = " and ".join(f"{v} in lane {q}" for q, v in _blocked_hvs(scenario)) or "none"
    since = "the swarm run's overtaking decision" + (
        f" (t = {paired_from_s:g} s)" if paired_from_s is not None else ""
    )
    paper_regroup = PAPER_BEHAVING_STEPS * PAPER_BEHAVING_INTERVAL_S
    return {
        "speed": (
            f"Platoon average speed = mean of every CAV speed sample (all {scenario.cav.count} "
            f"CAVs, every SUMO step of {sim.step_length_s:g} s) in the evaluation window "
            f"{ev.start_s:g}-{ev.end_s:g} s; minimum and maximum = the extreme samples; "
            "variance = population variance of the same samples."
        ),
        "gain": (
            f"Mobility gain = (platoon average speed / the {BASELINE} run's platoon average "
            "speed - 1) x 100 %, same traffic and seed. The paper's CACC speed is "
            f"{PAPER_SPEED_MPS} / {1 + PAPER_GAIN_PCT / 100:.4f} = {PAPER_CACC_SPEED_MPS:.2f} m/s."
        ),
        "travel_time": (
            "Travel time = mean over the CAVs of the time from the CAV's first sample in the "
            f"window until its front bumper has advanced {ev.travel_distance_m:g} m; empty when "
            "a CAV does not get that far inside the window."
        ),
        "gap": (
            "CAV following distance = bumper-to-bumper gap from a CAV to the vehicle (CAV or HV) "
            "right ahead of it in the lane SUMO reports it on, every step of the window; mean "
            "and minimum over all CAVs and steps. Excess over the desired distance = (mean / "
            f"{scenario.cav.desired_gap_m:g} m - 1) x 100 % (the paper: {PAPER_GAP_MEAN_M:.2f} m "
            f"vs {PAPER_DESIRED_GAP_M:g} m = {PAPER_GAP_EXCESS_PCT:g} %)."
        ),
        "upstream": (
            "Upstream HVs = the HVs whose front bumper is behind the front bumper of the "
            "swarm's leading CAV at the overtaking decision (t_start; at the window start for a "
            "run that never decides), the slow HV being overtaken left out, ranked per lane "
            f"nearest first, at most {ev.upstream_ranks} per lane (summary.json's ranking). #1 "
            f"is thus the HV beside the platoon in a side lane ({blocked}) and the first HV "
            f"behind the platoon in its lane (lane {scenario.scene.platoon_lane}). Speed "
            f"reduction, paired with the {BASELINE} run = max(0, (v_{BASELINE} - v_run) / "
            f"v_{BASELINE} x 100) %, where v_run is the HV's minimum speed in this run and "
            f"v_{BASELINE} the same HV's minimum speed in the {BASELINE} run (same traffic and "
            f"seed, no manoeuvre), both from {since} to the window end ({ev.end_s:g} s), for "
            f"every run, so the columns compare; the {BASELINE} column is 0 by construction. "
            "Computed from the runs' trajectories.parquet. The paper's "
            f"{len(PAPER_UPSTREAM_REDUCTION_PCT)} numbers are compared with the "
            f"{lane_name(compared_lane, n_lanes)} lane (lane {compared_lane}), the lane of its "
            "Fig. 11, where a CAV blocks an HV to open the cut-through gap."
        ),
        "upstream_summary": (
            "summary.json's own upstream speed reduction (secondary table), for the same ranked "
            "HVs = max(0, (v_ref - v_min) / v_ref x 100) %, where v_ref is the HV's speed at the "
            "run's reference time (the decision, or the window start for a run that never "
            "decides) and v_min its minimum speed from then to the window end: any change of "
            "speed an HV is going through at the reference time (a rise from its start speed, "
            "see below) counts in it."
        ),
        "influenced": (
            f"Influenced upstream HVs = how many of the ranked upstream HVs of a lane (at most "
            f"{ev.upstream_ranks}) have a speed reduction above {INFLUENCE_THRESHOLD_PCT:g} % "
            "(the paired reduction in the main table, summary.json's in the secondary one). "
            f"The paper: within {PAPER_INFLUENCED} following HVs (Section IV-E)."
        ),
        "upstream_gap": (
            "Minimum upstream following distance / time headway = the smallest bumper-to-bumper "
            "gap / gap divided by the HV's own speed, over the ranked upstream HVs of every lane "
            "and every step from the decision to the window end."
        ),
        "overtake": (
            "Overtake: t_start = the overtaking decision; all CAVs past = from when on every "
            "CAV's rear bumper stays ahead of the slow HV's front bumper (t_end); regrouped = "
            "from when on the CAVs also stay one platoon in one lane (t_regrouped). Behaving "
            f"steps = ceil((end of the manoeuvre - t_start) / {interval:g} s), the end being "
            "when the swarm controller hands back to cruising. The paper plans "
            f"{PAPER_BEHAVING_STEPS} behaving steps of {PAPER_BEHAVING_INTERVAL_S:g} s "
            f"({paper_regroup:g} s: cut-through done at {PAPER_PASS_S:g} s, platoon at "
            f"{PAPER_REGROUP_S:g} s)."
        ),
        "safety": (
            "Collisions = pairs of vehicles SUMO reports physically overlapping; hard brakes = "
            f"vehicles of any kind that ever decelerated harder than {metrics.HARD_BRAKE_MPS2:g} "
            "m/s²; teleports = vehicles SUMO removed and reinserted (switched off: must stay 0)."
        ),
    }


# --------------------------------------------------------------------------------------------
# comparisons


def _rows(report: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    return {r["key"]: r for r in report["rows"]}


def _value(report: Mapping[str, Any], key: str, run: str = FOCUS) -> Any:
    return _rows(report).get(key, {}).get(run)


def _paper_table(report: Mapping[str, Any]) -> list[str]:
    compared = []
    for r in report["rows"]:
        ours, paper = r.get(FOCUS), r.get("paper")
        if isinstance(paper, bool) or paper is None or ours is None or isinstance(ours, bool):
            continue
        d = r["digits"]
        rel = f", {(ours / paper - 1) * 100:+.0f} %" if paper != 0 else ""
        compared.append(
            f"| {r['measure']} | {fmt(paper, d)} | {fmt(ours, d)} | {fmt(ours - paper, d)}{rel} |"
        )
    return [
        f"Every measure the paper gives as a number, against ours ({FOCUS} run):\n",
        "| measure | paper | ours | ours - paper |\n| --- | --- | --- | --- |",
        "\n".join(compared) + "\n",
    ]


def _target_hv_speed_mps(scenario: Scenario) -> float | None:
    return next((h.desired_speed_mps for h in scenario.scene.hv if h.role == "target"), None)


def differences(report: Mapping[str, Any], scenario: Scenario) -> list[str]:
    """Markdown paragraphs comparing the swarm's numbers with the paper's, then why they
    differ, every number from the report (the runs) or the scenario."""
    lines: list[str] = []
    if report["runs"].get(FOCUS, {}).get("status") == "ok":
        lines += _paper_table(report)
        lines += _measured_differences(report, scenario)
        lines += _upstream_differences(report)
    else:
        lines.append(f"The {FOCUS} run did not finish: no measure to compare with the paper.\n")
    lines.append("\nWhy our numbers differ:\n")
    lines += [f"{i}. {text}" for i, text in enumerate(_reasons(report, scenario), start=1)]
    return lines


def _measured_differences(report: Mapping[str, Any], scenario: Scenario) -> list[str]:
    v = lambda key, run=FOCUS: _value(report, key, run)  # noqa: E731
    lines = []
    ev = scenario.evaluation
    speed, base, gain = v("cav.mean_speed"), v("cav.mean_speed", BASELINE), v("cav.mobility_gain")
    if None not in (speed, base, gain):
        regrouped = report["facts"].get("t_regrouped_s")
        after = (
            f", and it includes the cruise after the regroup (from t = {regrouped:.1f} s) at up "
            f"to {scenario.cav.cruising_speed_mps:g} m/s"
            if regrouped is not None and regrouped < ev.end_s
            else ""
        )
        lines.append(
            f"* **Mobility.** Our {BASELINE} platoon drives at {base:.2f} m/s (the paper's "
            f"{PAPER_CACC_SPEED_MPS:.2f} m/s) behind the slow HV, whose desired speed is "
            f"{fmt(_target_hv_speed_mps(scenario))} m/s. The swarm averages {speed:.2f} m/s, a "
            f"gain of {gain:.2f} % against the paper's {PAPER_GAIN_PCT} %. The gain depends on "
            "the averaging window, which the paper does not state: ours is "
            f"{ev.start_s:g}-{ev.end_s:g} s{after}."
        )
    gm, gmin = v("cav.gap_mean"), v("cav.gap_min")
    if gm is not None and gmin is not None:
        lines.append(
            f"* **Safety.** Mean CAV following distance {gm:.2f} m (paper "
            f"{PAPER_GAP_MEAN_M:.2f} m), minimum {gmin:.2f} m (paper: above "
            f"{scenario.cav.min_gap_m:g} m). The mean mixes the desired distance "
            f"({scenario.cav.desired_gap_m:g} m) the CAVs keep while following in one lane with "
            "the gaps while they are spread over the grid's cells (whole cells of "
            f"{scenario.cell_length_m:g} m minus a car length); how long each lasts inside the "
            "window sets the mean."
        )
    steps, dur, pas = v("overtake.behaving_steps"), v("overtake.duration_s"), v("overtake.pass_s")
    if steps is not None and dur is not None:
        ratio = scenario.cell_length_m / PAPER_CELL_LENGTH_M
        cells = (
            f"Our cells are {scenario.cell_length_m:g} m long, as the paper's"
            if ratio == 1
            else f"Our cells are {scenario.cell_length_m:g} m long instead of "
            f"{PAPER_CELL_LENGTH_M:g} m, so one behaving step moves a CAV {ratio:.3g} times as "
            "far relative to the slow HV"
        )
        lines.append(
            f"* **Overtake.** {steps} behaving steps of {scenario.planner.behaving_interval_s:g} "
            f"s and {dur:.1f} s from the decision to the regrouped platoon ({fmt(pas, 1)} s "
            f"until every CAV is past the slow HV) against the paper's {PAPER_BEHAVING_STEPS} "
            f"steps, {PAPER_REGROUP_S:g} s and {PAPER_PASS_S:g} s. {cells}."
        )
    return lines


def _upstream_differences(report: Mapping[str, Any]) -> list[str]:
    """The upstream paragraph: the paired numbers of the swarm run."""
    rows, lane = report["rows"], report["compared_lane"]
    reduction = per_lane(rows, "upstream.reduction.", ".rank1")
    if not reduction or all(r.get(FOCUS) is None for r in reduction.values()):
        return []
    by_key = {r["key"]: r for r in rows}
    ranked = [
        by_key.get(f"upstream.reduction.lane{lane}.rank{k}")
        for k in range(1, len(PAPER_UPSTREAM_REDUCTION_PCT) + 1)
    ]
    ranked = [r for r in ranked if r is not None and r.get(FOCUS) is not None]
    window = report.get("upstream_window_s") or [None, None]
    paper = ", ".join(f"{x:.2f}" for x in PAPER_UPSTREAM_REDUCTION_PCT)
    text = (
        f"* **Upstream traffic.** Against the same HVs in the {BASELINE} run (from the decision, "
        f"t = {fmt(window[0])} s, to {fmt(window[1], 0)} s), the 1st-{len(ranked)}th following "
        f"HVs of lane {lane} (the paper's Fig. 11 lane) slow down by "
        + ", ".join(f"{r['vehicles'][FOCUS]} {fmt(r[FOCUS])} %" for r in ranked)
        + f" (paper {paper} %). "
    )
    blocked = {
        e["vehicle"]
        for e in (report.get("upstream_paired") or {}).get(FOCUS) or []
        if e["role"] == "blocked"
    }
    firsts = [
        f"lane {q}: {r['vehicles'][FOCUS]}"
        + (" (blocked beside the platoon)" if r["vehicles"][FOCUS] in blocked else "")
        + f" {fmt(r[FOCUS])} %"
        for q, r in sorted(reduction.items(), reverse=True)
        if r.get(FOCUS) is not None
    ]
    text += "The first following HV of each lane: " + "; ".join(firsts) + ". "
    influenced = per_lane(rows, "upstream.influenced.")
    text += (
        f"HVs slowed by more than {INFLUENCE_THRESHOLD_PCT:g} %: "
        + ", ".join(
            f"{fmt(r.get(FOCUS), 0)} in lane {q}"
            for q, r in sorted(influenced.items(), reverse=True)
        )
        + f" (paper: within {PAPER_INFLUENCED}). "
    )
    target = (report.get("overtaken_paired") or {}).get(FOCUS)
    if target and target.get("speed_reduction_pct") is not None:
        text += (
            f"The slow HV itself ({target['vehicle']}, left out of the ranking) drops to "
            f"{fmt(target['min_speed_mps'])} m/s, {fmt(target['speed_reduction_pct'])} % below "
            f"its speed in the {BASELINE} run. "
        )
    secondary = {r["key"]: r for r in report.get("upstream_summary_rows", [])}
    old = [
        secondary.get(f"upstream.summary.reduction.lane{lane}.rank{k}")
        for k in range(1, len(ranked) + 1)
    ]
    if old and all(r is not None and r.get(FOCUS) is not None for r in old):
        text += (
            "summary.json's own reductions of the same HVs (secondary table) are "
            + ", ".join(fmt(r[FOCUS]) for r in old)
            + " %, measured against each HV's speed at the decision."
        )
    return [text]


def _reasons(report: Mapping[str, Any], scenario: Scenario) -> list[str]:
    """Why our numbers differ from the paper's: the set-up, with the scenario's values and what
    the runs measured."""
    hv, sim, scene, cav = scenario.hv, scenario.simulation, scenario.scene, scenario.cav
    facts = report["facts"]
    cell = scenario.cell_length_m
    out = [
        f"**Simulator.** SUMO (libsumo, step {sim.step_length_s:g} s) instead of the authors' "
        f"MATLAB platform; the HVs follow SUMO's IDM with a = {hv.accel_mps2:g} m/s², b = "
        f"{hv.decel_mps2:g} m/s², s0 = {hv.min_gap_m:g} m, delta = {hv.delta:g} and T = "
        f"{hv.headway_s:g} s (the paper cites its HV model without values), and "
        + ("change lanes on their own." if hv.lane_changes else "keep their lanes.")
    ]
    if cell == PAPER_CELL_LENGTH_M:
        out.append(f"**Cell length {cell:g} m**, the paper's Section IV-C value.")
    else:
        coarser = "fewer rows and coarser" if cell > PAPER_CELL_LENGTH_M else "more rows and finer"
        out.append(
            f"**Cell length {cell:g} m, not {PAPER_CELL_LENGTH_M:g} m** (`[cell] rule = "
            f'"{scenario.cell.rule}"`). Section II-B-1 defines a cell as the CAV length plus the '
            f"safety distance ({cav.length_m:g} + {cav.desired_gap_m:g} m); Section IV-C lists "
            f"{PAPER_CELL_LENGTH_M:g} m, which would put CAVs of adjacent rows bumper to bumper "
            f"with {cav.length_m:g} m CAVs. Our cells mean {coarser} moves, so behaving steps "
            "and the gaps while swarming differ."
        )
    out.append(
        "**Sublane model, not a bicycle model.** SUMO moves the CAVs laterally through its "
        f"sublane model ({sim.lateral_resolution_m:g} m resolution, lateral speed capped at "
        f"{cav.max_lateral_speed_mps:g} m/s); the paper tracks a front-wheel angle. A CAV "
        "between two lanes counts in the lane SUMO reports it on, for gaps and for the upstream "
        "ranking."
    )
    start = (
        f"Our upstream HVs start {scene.upstream_gap_m:g} m apart at "
        f"{scene.upstream_speed_mps:g} m/s"
    )
    rise = (facts.get("upstream_surge_mps") or {}).get(BASELINE)
    if rise is not None:  # the baseline changes no lane: what its HVs do comes from the start
        start += (
            f"; in the {BASELINE} run, where no CAV changes lanes, the fastest of them rises "
            f"{rise:.2f} m/s above its start speed: that start is "
            + ("not" if rise >= SURGE_MIN_MPS else "close to")
            + " an IDM equilibrium with these parameters"
        )
    start += "."
    out.append(
        "**The scene's geometry.** The paper gives the speeds and the upstream spacing but not "
        "where the slow, left-rear and right-rear HVs are; ours are in the scenario file "
        f"({scenario.path.name}). {start}"
    )
    window = report.get("upstream_window_s")
    since = f" (t = {window[0]:g} s)" if window else ""
    out.append(
        "**Measurement windows.** The paper does not say over which time its averages run; "
        f"ours are over the evaluation window ({scenario.evaluation.start_s:g}-"
        f"{scenario.evaluation.end_s:g} s), the upstream measures from the decision{since} on."
    )
    out.append(_regroup_reason(facts, scenario))
    return out


def _regroup_reason(facts: Mapping[str, Any], scenario: Scenario) -> str:
    text = (
        "**Regrouping.** Our swarm plans inside the grid, which moves at the slow HV's speed, "
        "until every CAV is past it; then the cruise mode re-forms the platoon at the cruising "
        f"speed ({scenario.cav.cruising_speed_mps:g} m/s)."
    )
    low, t_end, t_reg = (
        facts.get(k) for k in ("regroup_min_speed_mps", "t_end_s", "t_regrouped_s")
    )
    if None not in (low, t_end, t_reg):
        text += (
            f" Between all CAVs past ({t_end:.1f} s) and regrouped ({t_reg:.1f} s) the platoon's "
            f"average speed goes down to {low:.2f} m/s (cruising speed "
            f"{scenario.cav.cruising_speed_mps:g} m/s; Fig. 9)."
        )
    return text + " The paper's speed profile (its Fig. 9) is not given numerically."


def capped_paragraph(report: Mapping[str, Any], scenario: Scenario) -> list[str]:
    """What capping the CAVs at the cruising speed costs, from the capped and the default
    swarm runs (empty when the report has no capped run)."""
    if CAPPED not in report["runs"]:
        return []
    cap = scenario.cav.cruising_speed_mps
    head = (
        f"`{CAPPED}` is the swarm with `[cav] max_speed_mps` set to the cruising speed, "
        f"{cap:g} m/s (the `{FOCUS}` run: {scenario.cav.max_speed_mps:g} m/s)."
    )
    if any(report["runs"][r]["status"] != "ok" for r in (CAPPED, FOCUS)):
        return [head + " One of the two runs did not finish: nothing to compare."]
    v = lambda key, run: _value(report, key, run)  # noqa: E731
    top, top_free = v("cav.max_speed", CAPPED), v("cav.max_speed", FOCUS)
    speed, free = v("cav.mean_speed", CAPPED), v("cav.mean_speed", FOCUS)
    parts = [
        head,
        f"Its fastest CAV sample is {fmt(top)} m/s ({FOCUS}: {fmt(top_free)} m/s).",
    ]
    if speed is not None and free is not None:
        change = speed - free
        verb = "costs" if change < 0 else "changes"
        parts.append(
            f"The cap {verb} {abs(change):.2f} m/s of platoon average speed ({speed:.2f} vs "
            f"{free:.2f} m/s, {(speed / free - 1) * 100:+.1f} %; gain over {BASELINE} "
            f"{fmt(v('cav.mobility_gain', CAPPED))} vs {fmt(v('cav.mobility_gain', FOCUS))} %)."
        )
    for key, what in (
        ("overtake.pass_s", "Decision to all CAVs past the slow HV"),
        ("overtake.duration_s", "Decision to the regrouped platoon"),
    ):
        a, b = v(key, CAPPED), v(key, FOCUS)
        if a is not None and b is not None:
            parts.append(f"{what}: {a:.1f} s vs {b:.1f} s ({a - b:+.1f} s).")
        elif b is not None:
            parts.append(f"{what}: not reached in the run ({FOCUS}: {b:.1f} s).")
    parts.append(
        f"Minimum CAV gap {fmt(v('cav.gap_min', CAPPED))} vs {fmt(v('cav.gap_min', FOCUS))} m, "
        f"collisions {fmt(v('safety.collisions', CAPPED))} vs "
        f"{fmt(v('safety.collisions', FOCUS))}."
    )
    return [" ".join(parts)]


# --------------------------------------------------------------------------------------------
# report.md


def _paper_cell(row: Mapping[str, Any]) -> str:
    if row.get("paper_text"):
        return str(row["paper_text"])
    return "—" if row.get("paper") is None else fmt(row["paper"], row["digits"])


def _ranks_an_hv(row: Mapping[str, Any], columns: Sequence[str]) -> bool:
    """False for an upstream reduction row whose rank holds no HV in any run."""
    vehicles = row.get("vehicles")
    return vehicles is None or any(vehicles.get(c) for c in columns)


def _table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> list[str]:
    lines = [
        "| measure | paper | " + " | ".join(columns) + " |",
        "| --- | --- |" + " --- |" * len(columns),
    ]
    for row in rows:
        if _ranks_an_hv(row, columns):
            cells = [fmt(row[c], row["digits"]) for c in columns]
            lines.append(f"| {row['measure']} | {_paper_cell(row)} | " + " | ".join(cells) + " |")
    return lines


def render_markdown(report: Mapping[str, Any]) -> str:
    columns = report["controllers"]
    window = report.get("upstream_window_s") or [None, None]
    out = [
        "# Reproduction of the paper's evaluation (Section IV)",
        "",
        f"Scenario `{report['scenario']}` ({report['scenario_file']}), seed {report['seed']}, "
        f"evaluation window {report['scenario_info']['window']}; generated "
        f"{report['created_utc']} by `sumo-swarm reproduce` in {fmt(report['wall_s'], 1)} s.",
        "",
        "## Runs",
        "",
        "| run | controller | scenario changes | status | wall (s) | outputs | error |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for c in columns:
        r = report["runs"][c]
        changes = ", ".join(f"`{k} = {v}`" for k, v in r["changes"].items()) or "—"
        out.append(
            f"| {c} | {r['controller']} | {changes} | {r['status']} | "
            f"{fmt(r['wall_s'], 1)} | [{r['dir']}]({r['dir']}/) | {r['error'] or ''} |"
        )
    out += [
        "",
        "## Measures (Section IV-E)",
        "",
        f"The upstream HVs' speed reductions pair each run with the {BASELINE} run, HV by HV, "
        f"from the swarm's decision (t = {fmt(window[0])} s) to {fmt(window[1], 0)} s "
        "(definitions below); every other number is read from the runs' summary.json. "
        "Upstream ranks no run has an HV for are left out here (report.json has every "
        "rank).",
        "",
    ]
    out += _table(report["rows"], columns)
    out += [
        "",
        "The upstream HV each rank refers to, per run (both tables):",
        "",
        "| measure | " + " | ".join(columns) + " |",
        "| --- |" + " --- |" * len(columns),
    ]
    for row in report["rows"]:
        if "vehicles" in row and _ranks_an_hv(row, columns):
            label = row["measure"].removeprefix("speed reduction of ").removesuffix(" (%)")
            names = [row["vehicles"][c] or "—" for c in columns]
            out.append(f"| {label} | " + " | ".join(names) + " |")
    out += [
        "",
        "### Upstream HVs as summary.json measures them (secondary)",
        "",
        "The same HVs, each reduction against the HV's own speed at the run's reference "
        "time (summary.json's `upstream[].speed_reduction_pct`, definition below).",
        "",
    ]
    out += _table(report.get("upstream_summary_rows", []), columns)
    out += ["", "### Definitions", ""]
    out += [f"* {text}" for text in report["definitions"].values()]
    out += [
        "",
        f"### Targets ({FOCUS})",
        "",
        "| target | value | where | met | threshold from |",
        "| --- | --- | --- | --- | --- |",
    ]
    for t in report["targets"]:
        met = "—" if t["met"] is None else ("yes" if t["met"] else "**no**")
        out.append(
            f"| {t['target']} | {fmt(t['value'])} | {t.get('where') or ''} | {met} | "
            f"{t['origin']} |"
        )
    if report.get("capped"):
        out += ["", "## CAVs capped at the cruising speed", "", *report["capped"]]
    out += ["", "## Figures", ""]
    captions = {
        **FIGURES,
        "manoeuvre": "The manoeuvre, replayed (`sumo-swarm replay` of the swarm run)",
    }
    for name, caption in captions.items():
        if name in report["figures"]:
            out += [f"### {caption}", "", f"![{caption}]({report['figures'][name]})", ""]
        elif name in report["figure_errors"]:
            out += [f"### {caption}", "", f"Not drawn: {report['figure_errors'][name]}", ""]
    if not report["complete"]:
        out += ["*Figures are drawn once every run has finished.*", ""]
    out += ["## Where we differ from the paper and why", "", *report["differences"]]
    return "\n".join(out) + "\n"
