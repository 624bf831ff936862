"""Work across runs: batch sweeps (locally or on Ray), traffic-impact tables, the paper's
reproduction, figures and replays. Imports every layer below it (sim, controllers, config,
core)."""
