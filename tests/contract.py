"""The keys of summary.json that users' scripts rely on (../shared/contract.md)."""

from __future__ import annotations

SUMMARY_KEYS = {
    "schema", "scenario", "controller", "seed", "step_length_s", "sim_end_s",
    "cav", "overtake", "safety", "upstream", "planner", "timing", "swarms", "network",
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
