"""summary.json (schema ``sumo-swarm/summary/1``, see the output contract) from a run's outputs."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from sumo_swarm.checks import finite_or_none
from sumo_swarm.core.swarming.account import COMPLETED, overtake_counts, overtake_outcome
from sumo_swarm.core.swarming.decision import REGROUPED_GAP_FACTOR
from sumo_swarm.sim import metrics
from sumo_swarm.sim.measured import MeasureErrors
from sumo_swarm.sim.metrics import EvaluationWindow

if TYPE_CHECKING:
    from sumo_swarm.config import Scenario
    from sumo_swarm.sim.bridge import SumoSession
    from sumo_swarm.sim.scene import Scene

SCHEMA = "sumo-swarm/summary/1"
REGROUP_LAT_TOL_M = 0.5  # a CAV counts as "in" its lane when its centre is this close [m]
# How long after a manoeuvre's end [s] its regrouping is watched at most (sooner: the platoon's
# next manoeuvre, or the end of the run): the regrouped platoon must hold to the watch's end.
REGROUP_WATCH_S = 120.0
# rows_of(cav_ids, target, t_from_s, t_to_s): the trajectory rows overtake_times_s needs of one
# manoeuvre, from t_from_s to t_to_s [s]
RowsOf = Callable[[tuple[str, ...], str, float, float], pd.DataFrame]


def overtake_progress(
    df: pd.DataFrame, cav_ids: tuple[str, ...], target: str | None, max_gap_m: float
) -> pd.DataFrame:
    """Per step: whether every CAV is past ``target`` and whether they form one platoon.

    *Past*: the rear bumper of every CAV on the road is ahead of the target's front bumper
    (False while the target is not on the road). *Platoon*: every CAV in the lane of the
    front-most CAV (the platoon may regroup in any lane, not only the one it started in),
    within ``REGROUP_LAT_TOL_M`` of that lane's centre, no other vehicle between the first and
    the last of them in that lane (vehicles on edges no CAV is on, e.g. a ramp beside the road,
    do not count), and no gap between consecutive CAVs above ``max_gap_m`` [m].
    Returns a frame indexed by time with boolean columns ``past`` and ``platoon``.
    """
    if df.empty or not cav_ids:
        return pd.DataFrame(columns=["past", "platoon"], dtype=bool)
    wide = df.pivot_table(index="time_s", columns="vehicle", values="s_m", observed=True)
    present = [c for c in cav_ids if c in wide.columns]
    if len(present) < len(cav_ids):
        missing = pd.DataFrame(
            np.nan, index=wide.index, columns=[c for c in cav_ids if c not in wide.columns]
        )
        wide = pd.concat([wide, missing], axis=1)
    lengths = df.groupby("vehicle", observed=True)["length_m"].first()
    cav_s = wide[list(cav_ids)]
    cav_rear = cav_s - lengths.reindex(list(cav_ids)).to_numpy()
    if target is not None and target in wide.columns:
        past = (cav_rear.min(axis=1) > wide[target]).fillna(False)
    else:
        past = pd.Series(False, index=wide.index)
    in_lane = df[df["vehicle"].isin(cav_ids)]
    # The lane of the front-most CAV at each step: the platoon's lane, wherever it regroups.
    head_lane = in_lane.sort_values("s_m").groupby("time_s", observed=True)["lane"].last()
    in_lane = in_lane.join(head_lane.rename("head_lane"), on="time_s")
    in_lane["ok"] = (in_lane["lane"] == in_lane["head_lane"]) & (
        in_lane["lat_m"].abs() < REGROUP_LAT_TOL_M
    )
    ok_all = in_lane.pivot_table(
        index="time_s", columns="vehicle", values="ok", aggfunc="first", observed=True
    )
    ok_all = ok_all.reindex(index=wide.index, columns=list(cav_ids)).fillna(False).astype(bool)
    lane_ok = ok_all.all(axis=1)
    ordered = np.sort(cav_s.to_numpy(dtype=float), axis=1)
    sorted_rear = ordered - lengths.reindex(list(cav_ids)).mean()
    gaps = sorted_rear[:, 1:] - ordered[:, :-1]
    gaps_ok = np.all(gaps <= max_gap_m, axis=1) if gaps.shape[1] else np.ones(len(wide), bool)
    # No foreign vehicle between the platoon's tail and head in that lane, on the road the
    # CAVs are on: lane 0 of an on-ramp is not the platoon's lane, whatever its index.
    hv = df[~df["vehicle"].isin(cav_ids)].join(head_lane.rename("head_lane"), on="time_s")
    hv = hv[hv["lane"] == hv["head_lane"]]
    if "edge" in df.columns:
        cav_edges = in_lane[["time_s", "edge"]].astype({"edge": str}).drop_duplicates()
        hv = hv.astype({"edge": str}).merge(cav_edges, on=["time_s", "edge"], how="inner")
    head = cav_s.max(axis=1)
    tail = cav_s.min(axis=1)
    intruders = hv.join(head.rename("head"), on="time_s").join(tail.rename("tail"), on="time_s")
    between = (intruders["s_m"] > intruders["tail"]) & (intruders["s_m"] < intruders["head"])
    intruded = intruders[between]
    clean = ~wide.index.isin(intruded["time_s"].unique())
    platoon = lane_ok & pd.Series(gaps_ok & clean, index=wide.index)
    return pd.DataFrame({"past": past.astype(bool), "platoon": platoon.astype(bool)})


def pass_times_s(
    df: pd.DataFrame, cav_ids: tuple[str, ...], target: str | None
) -> dict[str, float | None]:
    """The first time [s] each CAV's rear bumper was ahead of ``target``'s front bumper, both
    on the road (None: it never was)."""
    out: dict[str, float | None] = {c: None for c in cav_ids}
    if df.empty or target is None:
        return out
    lengths = df.groupby("vehicle", observed=True)["length_m"].first()
    target_s = df.loc[df["vehicle"] == target, ["time_s", "s_m"]].set_index("time_s")["s_m"]
    cav = df[df["vehicle"].isin(cav_ids)][["time_s", "vehicle", "s_m"]]
    cav = cav.join(target_s.rename("target_s"), on="time_s", how="inner")
    rear = cav["s_m"].to_numpy(dtype=float) - lengths.reindex(cav["vehicle"]).to_numpy()
    ahead = cav[rear > cav["target_s"].to_numpy(dtype=float)]
    first = ahead.groupby("vehicle", observed=True)["time_s"].min()
    out.update({str(v): float(t) for v, t in first.items() if str(v) in out})
    return out


def overtake_times_s(
    df: pd.DataFrame, cav_ids: tuple[str, ...], target: str | None, max_gap_m: float
) -> tuple[float | None, float | None]:
    """``(t_end_s, t_regrouped_s)`` of an overtake of ``target`` (None: not reached).

    ``t_end_s``: the first time by which every CAV has been past the target (each CAV's first
    pass, see :func:`pass_times_s`), whatever happens after (CAVs or the target leaving the
    road). ``t_regrouped_s``: the first time at or after ``t_end_s`` from which the CAVs form
    one platoon (:func:`overtake_progress`), ahead of the target while it is on the road, and
    keep doing so until the table ends or the first CAV leaves the road.
    """
    passed = pass_times_s(df, cav_ids, target)
    if not passed or any(t is None for t in passed.values()):
        return None, None
    t_end = max(t for t in passed.values() if t is not None)
    progress = overtake_progress(df, cav_ids, target, max_gap_m)
    cav = df[df["vehicle"].isin(cav_ids)]
    t_last = float(cav.groupby("vehicle", observed=True)["time_s"].max().min())
    on_road = df.loc[df["vehicle"] == target, "time_s"].unique() if target else []
    target_gone = ~progress.index.isin(on_road)
    ahead = progress["platoon"] & (progress["past"] | target_gone)
    times = ahead.index.to_numpy(dtype=float)
    ahead = ahead[(times >= t_end) & (times <= t_last)]
    return t_end, _first_time_holding(ahead)


def _first_time_holding(flags: pd.Series) -> float | None:
    """First time after which ``flags`` stays True to the end (None if false at the end)."""
    if flags.empty or not bool(flags.iloc[-1]):
        return None
    values = flags.to_numpy()
    false_idx = np.flatnonzero(~values)
    start = 0 if false_idx.size == 0 else int(false_idx[-1]) + 1
    return float(flags.index[start])


def measure_manoeuvres(
    manoeuvres: Sequence[dict[str, Any]],
    rows_of: RowsOf,
    max_gap_m: float,
    errors: MeasureErrors | None = None,
) -> list[dict[str, Any]]:
    """The manoeuvres (the controller's account, :mod:`sumo_swarm.core.swarming.account`)
    with what the trajectories say of each completed one (:func:`overtake_times_s`, on its
    CAVs that got past and its target): ``t_past_s``, when every one of them had been past the
    target; ``regrouped`` and ``t_regrouped_s``, when they formed one platoon ahead of it and
    held it to the end of the watch (:data:`REGROUP_WATCH_S`, the platoon's next manoeuvre,
    or the run's end). Others: not measured (None, not regrouped). A measure that fails
    leaves its manoeuvre unmeasured, the reason in ``errors`` (``manoeuvres[i].times``)."""
    errors = errors if errors is not None else MeasureErrors()
    out = []
    for i, m in enumerate(manoeuvres):
        m = {**m, "t_past_s": None, "regrouped": False, "t_regrouped_s": None}
        cav_ids = tuple(m.get("past_ids") or ())
        if m["outcome"] == COMPLETED and m["target"] is not None and cav_ids:
            t_to = m["t_end_s"] + REGROUP_WATCH_S
            for later in manoeuvres[i + 1 :]:
                if later["platoon"] == m["platoon"]:
                    t_to = min(t_to, later["t_start_s"])
                    break
            span = (m["t_start_s"], t_to)
            t_past, t_regroup = errors.take(
                f"manoeuvres[{i}].times", _times_of, rows_of, cav_ids, m["target"], span,
                max_gap_m, default=(None, None),
            )  # fmt: skip
            m.update(t_past_s=finite_or_none(t_past), regrouped=t_regroup is not None,
                     t_regrouped_s=finite_or_none(t_regroup))  # fmt: skip
        out.append(m)
    return out


def _times_of(
    rows_of: RowsOf,
    cav_ids: tuple[str, ...],
    target: str,
    span_s: tuple[float, float],
    max_gap_m: float,
) -> tuple[float | None, float | None]:
    """:func:`overtake_times_s` of one manoeuvre, on its rows of ``span_s`` [s]."""
    return overtake_times_s(rows_of(cav_ids, target, *span_s), cav_ids, target, max_gap_m)


def rows_between(df: pd.DataFrame) -> RowsOf:
    """``rows_of`` (:data:`RowsOf`) on a table in memory: its rows in the time span."""
    tol = metrics.TIME_TOLERANCE_S

    def rows_of(cav_ids: tuple[str, ...], target: str, t_from_s: float, t_to_s: float):
        times = df["time_s"].to_numpy(dtype=float)
        return df[(times >= t_from_s - tol) & (times <= t_to_s + tol)]

    return rows_of


def manoeuvre_line(summary: dict[str, Any]) -> str:
    """What a person reads of a run's manoeuvres, in one line: how the first one went (its
    kind, target, CAVs past, regrouped or not, or the controller's own word for why it ended
    without every CAV past), how the last one on the same target went if there were more, how
    many there were in all, and where the CAVs stood at the end (``overtake.all_past``)."""
    listed = summary.get("manoeuvres") or []
    ot = summary.get("overtake") or {}
    if not listed:
        if ot.get("target") is None:
            return "no manoeuvre"
        past = "every CAV got past" if ot.get("completed") else "not every CAV got past"
        return f"no manoeuvre of the controller; {past} {ot['target']}"
    first = listed[0]
    text = f"overtake of {first['target']} ({_how_it_went(first)})"
    again = [
        m for m in listed[1:] if m["target"] == first["target"] and m["platoon"] == first["platoon"]
    ]
    if again:
        text += f", then ({_how_it_went(again[-1])})"
    if len(listed) > 1:
        counts = overtake_counts(listed)
        text += (
            f", {len(listed)} manoeuvres in all ({counts['overtakes_completed']} completed, "
            f"{counts['overtakes_aborted']} stopped, {counts['overtakes_running']} running)"
        )
    if "all_past" in ot:  # where the run ended, whatever the manoeuvres: the table's word
        if not ot["all_past"]:
            text += f"; at the end not every CAV past {first['target']}"
        else:
            platoon = "one platoon" if ot.get("all_past_regrouped") else "not one platoon"
            text += f"; at the end every CAV past {first['target']}, {platoon}"
    return text


def _how_it_went(m: dict[str, Any]) -> str:
    kind = str(m["kind"]).replace("_", " ")
    text = f"{kind} from {m['t_start_s']:.1f} s: {m['cavs_past']} of {m['cavs']} CAVs past"
    if m["outcome"] == COMPLETED:
        if m["regrouped"] and m["t_regrouped_s"] is not None:
            return text + f", regrouped at {m['t_regrouped_s']:.1f} s"
        return text + ", not regrouped"
    if m["outcome"] == "running":
        return text + ", still under way at the end"
    return text + f", stopped at {m['t_end_s']:.1f} s: {m.get('reason')}"


SWARM_KEYS = (
    "platoons_formed",
    "max_concurrent",
    "overtakes_started",
    "overtakes_completed",
    "overtakes_aborted",
)


def swarms_block(own: dict[str, Any] | None) -> dict[str, int]:
    """summary.json's ``swarms`` block: the controller's counts, 0 for any it does not keep (a
    controller without platoons: none formed, no overtakes)."""
    own = own or {}
    extra = {k: int(v) for k, v in own.items() if k not in SWARM_KEYS and isinstance(v, int)}
    return {**{k: int(own.get(k, 0)) for k in SWARM_KEYS}, **extra}


@dataclass(frozen=True)
class TableMeasures:
    """What summary.json measures on the trajectory table (the rest comes from the session and
    the controller): :func:`table_measures` on a table in memory, or
    :func:`sumo_swarm.sim.streamed.streamed_measures` a slice of steps at a time."""

    speed: dict[str, Any]  # metrics.cav_speed_stats
    gap: dict[str, Any]  # metrics.cav_gap_stats
    travel_time_s: float | None
    t_end_s: float | None  # overtake_times_s
    t_regrouped_s: float | None
    upstream: list[dict[str, Any]] | None  # metrics.upstream_impact
    min_ttc_s: float | None
    errors: dict[str, str] = field(default_factory=dict)  # the measures that failed, and why


def table_measures(
    df: pd.DataFrame,
    scenario: Scenario,
    cav_ids: tuple[str, ...],
    target: str | None,
    t_start_s: float | None,
    gap_table: pd.DataFrame | None = None,
) -> TableMeasures:
    """The summary's measures of the trajectory table ``df`` over the scenario's evaluation
    window; ``target`` and ``t_start_s``: the overtake's, as the controller reports them.
    ``gap_table``: :func:`metrics.gaps` of ``df`` when the caller has it (the recorder pairs
    the rows as it packs them, for the TTC conflicts).
    Each measure is taken on its own (:mod:`~sumo_swarm.sim.measured`): one that fails is None
    and its reason is in ``errors``."""
    ev = scenario.evaluation
    w = EvaluationWindow(ev.start_s, ev.end_s)
    m = MeasureErrors()
    # every follower and leader, once (None if the pairing fails: each measure of the pairs
    # then tries it on its own and fails with its reason)
    if gap_table is None:
        pairs = m.take("cav.gap", lambda: metrics.gaps(metrics.window(df, w)))
    else:  # each step is paired on its own: the window's pairs are those of its rows
        pairs = m.take("cav.gap", metrics.window, gap_table, w)
    t_end, t_regroup = m.take(
        "overtake.times", overtake_times_s, df, cav_ids, target,
        REGROUPED_GAP_FACTOR * scenario.cav.desired_gap_m, default=(None, None),
    )  # fmt: skip
    ref_time = t_start_s if t_start_s is not None else ev.start_s
    # The HVs behind the swarm's front at the decision: those beside the platoon, which the
    # swarm blocks, rank first in their lanes; the slow vehicle itself is left out.
    ref_w = metrics.upstream_window(ref_time, ev.end_s)
    upstream: list[dict[str, Any]] | None = []  # none: the manoeuvre began after the window
    if ref_w is not None:
        upstream = m.take(
            "upstream",
            metrics.upstream_impact,
            df,
            ref_time,
            n_rank=ev.upstream_ranks,
            window=ref_w,
            behind_of="front",
            exclude=[target] if target else [],
            # the pairs of the evaluation window hold this window's rows when it starts inside it
            gap_table=pairs if ref_time >= ev.start_s else None,
        )
    return TableMeasures(
        speed=m.take("cav.speed", metrics.cav_speed_stats, df, w, default={}),
        gap=m.take("cav.gap", metrics.cav_gap_stats, df, w, gap_table=pairs, default={}),
        travel_time_s=m.take(
            "cav.travel_time_s", metrics.travel_time_s, df, w, ev.travel_distance_m
        ),
        t_end_s=t_end,
        t_regrouped_s=t_regroup,
        upstream=upstream,
        min_ttc_s=m.take("safety.min_ttc_s", metrics.min_ttc_s, df, w, gap_table=pairs),
        errors=m.reasons,
    )


def build_summary(
    *,
    scenario: Scenario,
    controller: str,
    df: pd.DataFrame | None,
    scene: Scene,
    session: SumoSession,
    controller_summary: dict[str, Any],
    timing: dict[str, Any],
    hard_brakes: metrics.HardBrakeCounter | None = None,
    measures: TableMeasures | None = None,
    rows_of: RowsOf | None = None,
    gap_table: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """Assemble every key of the contract's summary.json (None where a key does not apply).

    ``hard_brakes``: counted during the run, of every vehicle whether recorded or not; without
    it they are counted on ``df``. ``measures``: the table's measures when the caller has them
    (a run whose table is on disk); else they are taken on ``df`` (``gap_table``: its
    :func:`metrics.gaps`, when the caller has it). ``rows_of``: the rows of each manoeuvre
    (:data:`RowsOf`) when the table is not ``df``.

    ``manoeuvres`` is the controller's list (a controller that keeps none: empty), measured
    on the trajectories (:func:`measure_manoeuvres`); ``overtake``'s outcome fields and
    ``swarms``' overtake counts are derived from it. A controller without manoeuvres of its
    own (the baselines) has its ``overtake`` block measured on the scene's slow vehicle: not
    triggered, completed when every CAV got past it."""
    own = controller_summary.get("overtake", {})
    listed = controller_summary.get("manoeuvres")
    first = listed[0] if listed else None
    target = first["target"] if first else scene.target_id
    t_start = first["t_start_s"] if first else None
    if measures is None:
        measures = table_measures(df, scenario, scene.cav_ids, target, t_start, gap_table)
    m = measures
    speed, gap, upstream = m.speed, m.gap, m.upstream
    max_gap_m = REGROUPED_GAP_FACTOR * scenario.cav.desired_gap_m
    errors = MeasureErrors()
    errors.reasons.update(m.errors)
    manoeuvres = measure_manoeuvres(
        listed or [], rows_of or rows_between(df), max_gap_m, errors=errors
    )
    if listed is None:  # no account of its own: what the table says of the scene's slow vehicle
        outcome = {
            "triggered": False,
            "completed": m.t_end_s is not None,
            "regrouped": m.t_regrouped_s is not None,
            "target": target,
            "t_start_s": None,
            "t_end_s": finite_or_none(m.t_end_s),
            "t_regrouped_s": finite_or_none(m.t_regrouped_s),
            "behaving_steps": None,
            "aborted": 0,
            "abort_reasons": {},
        }
    else:
        interval = own.get("behaving_interval_s") or scenario.planner.behaving_interval_s
        outcome = overtake_outcome(manoeuvres, interval)
    overtake = {
        **outcome,
        "lateral_holds": int(own.get("lateral_holds", 0)),
        "blocked_hv_min_accel_mps2": finite_or_none(own.get("blocked_hv_min_accel_mps2")),
        # Extra (not in the contract), measured alike for every controller on the trajectories:
        # every CAV got past the first target by the run's end, by whatever manoeuvres (the
        # first manoeuvre's own outcome is "completed"), and formed one platoon ahead of it.
        "all_past": m.t_end_s is not None,
        "all_past_regrouped": m.t_regrouped_s is not None,
    }
    extra = (
        "manoeuvres",
        "targets",
        "behaving_interval_s",
        "lateral_holds_per_manoeuvre",
        "lateral_yields",
        "waits_ahead",
        "blocked_hvs",
    )
    for key in extra:
        if key in own:  # extra (not in the contract): the swarm's own bookkeeping
            overtake[key] = own[key]
    collisions = {tuple(sorted((c.collider, c.victim))) for c in session.collisions}
    planner_keys = (
        "solves",
        "solve_ms_median",
        "solve_ms_p95",
        "solve_ms_max",
        "solve_cpu_ms_median",
        "solve_cpu_ms_p95",
        "solve_cpu_ms_max",
        "statuses",
        "fallbacks",
    )
    if hard_brakes is not None:
        brakes = (hard_brakes.count(), hard_brakes.count("cav"), hard_brakes.count("hv"))
    elif df is None:
        raise ValueError("build_summary: without the table, the hard brakes must be counted")
    else:
        by_kind = [df[df["kind"] == k] if len(df) else df for k in ("cav", "hv")]
        brakes = errors.take(
            "safety.hard_brakes",
            lambda: (metrics.hard_brakes(df), *(metrics.hard_brakes(d) for d in by_kind)),
            default=(None, None, None),
        )
    planner = {k: None for k in planner_keys}
    planner.update(controller_summary.get("planner", {}))
    return {
        "schema": SCHEMA,
        "scenario": scenario.name,
        "controller": controller,
        "seed": scenario.simulation.seed,
        "step_length_s": scenario.simulation.step_length_s,
        "sim_end_s": float(session.time_s),
        "cav": {
            "count": len(scene.cav_ids),
            "mean_speed_mps": finite_or_none(speed.get("mean_speed_mps")),
            "min_speed_mps": finite_or_none(speed.get("min_speed_mps")),
            "max_speed_mps": finite_or_none(speed.get("max_speed_mps")),
            "speed_var_m2ps2": finite_or_none(speed.get("speed_var_m2ps2")),
            "travel_time_s": finite_or_none(m.travel_time_s),
            "gap_mean_m": finite_or_none(gap.get("gap_mean_m")),
            "gap_min_m": finite_or_none(gap.get("gap_min_m")),
            "gap_min_cav_m": finite_or_none(gap.get("gap_min_cav_m")),  # CAV behind a CAV
            "gap_min_hv_m": finite_or_none(gap.get("gap_min_hv_m")),  # CAV behind an HV
            "lat_error_rms_m": finite_or_none(controller_summary.get("lat_error_rms_m")),
        },
        "overtake": overtake,
        "manoeuvres": manoeuvres,
        "safety": {
            "collisions": len(collisions),
            "hard_brakes": brakes[0],
            # Extra (not in the contract): the same count split by kind.
            "hard_brakes_cav": brakes[1],
            "hard_brakes_hv": brakes[2],
            "teleports": int(session.teleports),
            "min_ttc_s": finite_or_none(m.min_ttc_s),
        },
        "swarms": {**swarms_block(controller_summary.get("swarms")), **overtake_counts(manoeuvres)},
        # From SUMO's own outputs, filled once the simulation has ended (RunRecorder.finish).
        "network": None,
        "upstream": upstream,
        "planner": planner,
        # Extra (not in the contract): MPC solve time per CAV per solve, swarm only.
        "tracking": controller_summary.get("mpc"),
        # Extra: the speeds the swarm used and where they came from.
        "speeds": controller_summary.get("speeds"),
        "timing": {k: finite_or_none(v) for k, v in timing.items()},
        # Extra: the measures that failed (each None in its block), measure -> reason.
        "errors": errors.reasons,
    }
