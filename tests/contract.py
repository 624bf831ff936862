"""The keys of summary.json that users' scripts rely on (../shared/contract.md)."""

from __future__ import annotations

SUMMARY_KEYS = {
    "schema", "scenario", "controller", "seed", "step_length_s", "sim_end_s",
    "cav", "overtake", "safety", "upstream", "planner", "timing", "swarms", "network",
    "manoeuvres",
}  # fmt: skip
BLOCK_KEYS = {
    "cav": {"count", "mean_speed_mps", "min_speed_mps", "max_speed_mps", "speed_var_m2ps2",
            "travel_time_s", "gap_mean_m", "gap_min_m", "lat_error_rms_m"},
    "overtake": {"triggered", "completed", "regrouped", "target", "t_start_s", "t_end_s",
                 "t_regrouped_s", "behaving_steps"},
    "safety": {"collisions", "hard_brakes", "teleports", "min_ttc_s"},
    "planner": {"solves", "solve_ms_median", "solve_ms_p95", "solve_ms_max", "statuses",
                "fallbacks"},
    "timing": {"wall_s", "sumo_s", "controller_s", "realtime_factor"},
    "swarms": {"platoons_formed", "max_concurrent", "overtakes_started", "overtakes_completed",
               "overtakes_aborted"},
}  # fmt: skip
NETWORK_KEYS = {"vehicles", "travel_time_s", "delay_s", "throughput_vph",
                "hard_brakes_per_1000_vkm", "ttc_below_1_5s_events", "co2_g_per_km"}  # fmt: skip
UPSTREAM_KEYS = {"lane", "rank", "vehicle", "undisturbed_speed_mps", "min_speed_mps",
                 "speed_reduction_pct", "min_gap_m", "min_headway_s"}  # fmt: skip
TRAJECTORY_COLUMNS = {"time_s", "vehicle", "kind", "edge", "lane", "x_m", "y_m", "s_m", "lat_m",
                      "speed_mps", "accel_mps2"}  # fmt: skip


def assert_summary_contract(summary: dict) -> None:
    assert summary["schema"] == "sumo-swarm/summary/1"
    missing = SUMMARY_KEYS - set(summary)
    assert not missing, f"summary lacks {missing}"
    for block, keys in BLOCK_KEYS.items():
        lacking = keys - set(summary[block])
        assert not lacking, f"summary.{block} lacks {lacking}"
    if summary["network"] is not None:  # None: a run without SUMO's outputs ([outputs])
        lacking = NETWORK_KEYS - set(summary["network"])
        assert not lacking, f"summary.network lacks {lacking}"
    for row in summary["upstream"]:
        assert set(row) >= UPSTREAM_KEYS
    # every measure was taken (sim/measured.py: a failed one is None, its reason here)
    assert summary["errors"] == {}, f"summary measures failed: {summary['errors']}"


# --------------------------------------------------------------------------- manoeuvres
# Written from the events themselves, not with the package's fold (account.py), so that a
# fault in the fold shows.
MANOEUVRE_KEYS = {"platoon", "kind", "target", "t_start_s", "t_end_s", "cavs", "cavs_past",
                  "regrouped", "t_regrouped_s", "outcome"}  # fmt: skip
MANOEUVRE_KINDS = {"cells", "lane_pass", "one_by_one", "wait"}


def manoeuvre_problems(summary: dict, events: list[dict]) -> list[str]:
    """Where summary.json's ``manoeuvres``, ``overtake`` and ``swarms`` disagree with each
    other or with the run's events (empty: they agree).

    - every ``overtake_start`` event is one entry of the list, in order, and nothing else is;
      an entry's platoon, kind, target and start are its start event's;
    - an entry with an ``overtake_end`` event (same platoon and manoeuvre number) ended then:
      outcome ``completed`` if the event says completed, else ``aborted:<its reason>``, and
      its CAVs past are the event's and the ``cav_past`` events' count; one without is
      ``running`` with no end;
    - no ``overtake_end`` or ``cav_past`` event of a manoeuvre that never started;
    - regrouped only after a completed manoeuvre, with its time; CAVs past at most its CAVs;
    - ``overtake`` is the first entry (triggered when there is one; completed, regrouped,
      target, start, regroup time its own; an end time when completed and only then), its
      ``aborted`` and ``abort_reasons`` those of every entry;
    - ``swarms``' overtakes started, completed and aborted are the list's (and the events').
    """
    problems: list[str] = []
    listed = summary.get("manoeuvres")
    if listed is None:
        return ["summary has no manoeuvres list"]
    starts = [e for e in events if e.get("event") == "overtake_start"]
    key = lambda e: (e.get("platoon"), e.get("manoeuvre"))  # noqa: E731
    ends = {key(e): e for e in events if e.get("event") == "overtake_end"}
    passes: dict[tuple, set] = {}
    for e in events:
        if e.get("event") == "cav_past":
            passes.setdefault(key(e), set()).add(e.get("vehicle"))
    started = {key(e) for e in starts}
    for k in set(ends) - started:
        problems.append(f"overtake_end of a manoeuvre that never started: {k}")
    for k in set(passes) - started:
        problems.append(f"cav_past of a manoeuvre that never started: {k}")
    if len(listed) != len(starts):
        problems.append(f"{len(listed)} manoeuvres listed, {len(starts)} overtake_start events")
    for i, (m, e) in enumerate(zip(listed, starts, strict=False)):
        where = f"manoeuvres[{i}]"
        if not set(m) >= MANOEUVRE_KEYS:
            problems.append(f"{where} lacks {MANOEUVRE_KEYS - set(m)}")
            continue
        if m["kind"] not in MANOEUVRE_KINDS:
            problems.append(f"{where}: unknown kind {m['kind']!r}")
        start = (e.get("platoon") or 0, e.get("kind"), e.get("target"), e["time_s"])
        if (m["platoon"], m["kind"], m["target"], m["t_start_s"]) != start:
            problems.append(f"{where} {m} is not its start event {e}")
        end = ends.get(key(e))
        if end is None:
            if m["outcome"] != "running" or m["t_end_s"] is not None:
                problems.append(f"{where}: no overtake_end event, yet {m['outcome']}")
        else:
            outcome = "completed" if end["completed"] else f"aborted:{end['reason']}"
            if (m["outcome"], m["t_end_s"]) != (outcome, end["time_s"]):
                problems.append(f"{where}: {m['outcome']} at {m['t_end_s']}, its event says "
                                f"{outcome} at {end['time_s']}")  # fmt: skip
            if m["cavs_past"] != end.get("cavs_past") or m["cavs"] != end.get("cavs"):
                problems.append(f"{where}: CAVs past {m['cavs_past']} of {m['cavs']}, its event "
                                f"{end.get('cavs_past')} of {end.get('cavs')}")  # fmt: skip
        if m["cavs_past"] != len(passes.get(key(e), ())):
            problems.append(f"{where}: {m['cavs_past']} CAVs past, "
                            f"{len(passes.get(key(e), ()))} cav_past events")  # fmt: skip
        if not 0 <= m["cavs_past"] <= m["cavs"]:
            problems.append(f"{where}: {m['cavs_past']} of {m['cavs']} CAVs past")
        if m["regrouped"] and (m["outcome"] != "completed" or m["t_regrouped_s"] is None):
            problems.append(f"{where}: regrouped after {m['outcome']}, at {m['t_regrouped_s']}")
    problems += _derived_problems(summary, listed)
    return problems


def _derived_problems(summary: dict, listed: list[dict]) -> list[str]:
    """``overtake`` and ``swarms`` against the list (see :func:`manoeuvre_problems`)."""
    problems = []
    ot, sw = summary["overtake"], summary["swarms"]
    outcomes = [m["outcome"] for m in listed]
    reasons: dict[str, int] = {}
    for o in outcomes:
        if o.startswith("aborted:"):
            reasons[o[len("aborted:") :]] = reasons.get(o[len("aborted:") :], 0) + 1
    counts = {
        "overtakes_started": len(listed),
        "overtakes_completed": outcomes.count("completed"),
        "overtakes_aborted": sum(reasons.values()),
    }
    for k, v in counts.items():
        if sw.get(k) != v:
            problems.append(f"swarms.{k} = {sw.get(k)}, the list says {v}")
    if ot["triggered"] != bool(listed):
        problems.append(f"overtake.triggered = {ot['triggered']} with {len(listed)} manoeuvres")
    if not listed:
        if ot["t_start_s"] is not None or ot["aborted"]:
            problems.append("overtake has a start or give-ups, yet no manoeuvre")
        return problems
    first = listed[0]
    done = first["outcome"] == "completed"
    want = {
        "completed": done,
        "regrouped": first["regrouped"],
        "target": first["target"],
        "t_start_s": first["t_start_s"],
        "t_regrouped_s": first["t_regrouped_s"],
        "aborted": counts["overtakes_aborted"],
        "abort_reasons": reasons,
    }
    for k, v in want.items():
        if ot[k] != v:
            problems.append(f"overtake.{k} = {ot[k]!r}, the first manoeuvre says {v!r}")
    if (ot["t_end_s"] is not None) != done:
        problems.append(f"overtake.t_end_s = {ot['t_end_s']} after {first['outcome']}")
    return problems


def assert_manoeuvres_agree(summary: dict, events: list[dict]) -> None:
    problems = manoeuvre_problems(summary, events)
    assert not problems, "\n".join(problems)
