"""A user's road as a new user would build it, for trying the swarm on traffic it was not tuned for.

A 3-lane, 3 km highway (netbuild), SUMO's default vType for the traffic (Krauss, sigma 0.5, a
speed factor per vehicle), a flow of 2700 veh/h with ``departLane="best"`` and
``departSpeed="max"``, a truck (maxSpeed 14 m/s) and 5 CAVs (vType ``cav``, maxSpeed 25 m/s)
behind it in lane ``--lane``; step 0.1 s, 110 s. Then, side by side::

    python tools/open_road.py --out /tmp/open --lane 0
    for c in swarm cacc sumo-lc; do
        sumo-swarm run --sumocfg /tmp/open/user.sumocfg --cav-type cav --controller $c \\
            --out /tmp/open/$c
    done
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sumo_swarm.sim.netbuild import HighwaySpec, build_highway, edge_ids


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the network and sumocfg")
    ap.add_argument("--lane", type=int, default=1, help="lane of the truck and CAVs (default 1)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    spec = HighwaySpec(length_m=3000, lanes=3)
    net = build_highway(spec, args.out)
    lane = args.lane
    routes = [
        "<routes>",
        '  <vType id="car"/>',
        '  <vType id="truck" vClass="truck" maxSpeed="14"/>',
        '  <vType id="cav" maxSpeed="25" sigma="0"/>',
        f'  <route id="r" edges="{" ".join(edge_ids(spec))}"/>',
        f'  <vehicle id="truck" type="truck" route="r" depart="0" departLane="{lane}" '
        'departPos="320" departSpeed="14"/>',
        *(
            f'  <vehicle id="c{i}" type="cav" route="r" depart="0" departLane="{lane}" '
            f'departPos="{300 - 15 * i}" departSpeed="14"/>'
            for i in range(5)
        ),
        '  <flow id="f" type="car" route="r" begin="0" end="120" vehsPerHour="2700" '
        'departLane="best" departSpeed="max"/>',
        "</routes>",
    ]
    (args.out / "routes.rou.xml").write_text("\n".join(routes) + "\n", encoding="utf-8")
    (args.out / "user.sumocfg").write_text(
        f'<configuration><input><net-file value="{net.name}"/>'
        '<route-files value="routes.rou.xml"/></input>'
        '<time><step-length value="0.1"/><end value="110"/></time></configuration>\n',
        encoding="utf-8",
    )
    print(f"wrote {args.out / 'user.sumocfg'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
