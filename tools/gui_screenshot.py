"""A screenshot of sumo-gui while the swarm overtakes: the grid and the planned cells as drawn live.

Runs the tutorial's road (docs/tutorial.md, step 1) in a real sumo-gui window, the swarm
attached to its traci connection (``sumo_swarm.attach``, which draws the plan as polygons), and
has sumo-gui save its view at a moment of the manoeuvre (TraCI ``gui.screenshot``). Without a
display it starts a virtual one, Xvfb (Debian: ``apt-get install xvfb``).

    python tools/gui_screenshot.py [--out docs/img/sumo-gui.png] [--at 27] [--size 1400x520]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

OUT = ROOT / "docs" / "img" / "sumo-gui.png"
VIEW = "View #0"
DISPLAY = ":87"  # the virtual display's number when there is no display

ROUTES = """<routes>
    <vType id="cav" length="5" maxSpeed="30"/>
    <vType id="car" length="5" maxSpeed="30" carFollowModel="IDM"/>
    <vType id="truck" vClass="truck" length="12" maxSpeed="15" color="220,40,40"/>
    <route id="road" edges="A0B0"/>
    <vehicle id="truck0" type="truck" route="road" depart="0" departLane="0" departPos="250"
             departSpeed="15"/>
    <flow id="cav" type="cav" route="road" begin="0" number="5" period="2" departLane="0"
          departSpeed="max" color="31,119,180"/>
    <flow id="car" type="car" route="road" begin="0" end="60" vehsPerHour="900"
          departLane="random" departSpeed="max" color="150,150,150"/>
</routes>
"""
# The cell plan, the paper's method, always: on this road a free passing lane would otherwise
# take the platoon past as a unit (a lane pass, which has no cells to draw).
SETTINGS = """[swarm]
lane_pass = false
"""
CONFIG = """<configuration>
    <input>
        <net-file value="road.net.xml"/>
        <route-files value="road.rou.xml"/>
    </input>
    <time>
        <end value="90"/>
        <step-length value="0.1"/>
    </time>
</configuration>
"""


def make_road(where: Path) -> Path:
    """The tutorial's road: a 3-km, 3-lane straight road, a slow truck, five CAVs, cars."""
    subprocess.run(
        [
            "netgenerate", "--grid", "--grid.x-number", "2", "--grid.y-number", "1",
            "--grid.length", "3000", "--default.lanenumber", "3", "--default.speed", "33.33",
            "--no-turnarounds", "-o", str(where / "road.net.xml"),
        ],
        check=True,
        capture_output=True,
    )  # fmt: skip
    (where / "road.rou.xml").write_text(ROUTES, encoding="utf-8")
    (where / "swarm.toml").write_text(SETTINGS, encoding="utf-8")
    cfg = where / "road.sumocfg"
    cfg.write_text(CONFIG, encoding="utf-8")
    return cfg


def start_display() -> subprocess.Popen[bytes] | None:
    """Xvfb on DISPLAY when there is no display; None when there is one."""
    if os.environ.get("DISPLAY"):
        return None
    if shutil.which("Xvfb") is None:
        raise SystemExit("no display and no Xvfb: apt-get install xvfb")
    xvfb = subprocess.Popen(
        ["Xvfb", DISPLAY, "-screen", "0", "1600x1000x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.environ["DISPLAY"] = DISPLAY
    time.sleep(1.0)  # the server takes a moment to accept clients
    if xvfb.poll() is not None:
        raise SystemExit(f"Xvfb {DISPLAY} did not start")
    return xvfb


def screenshot(out: Path, at_s: float, size: tuple[int, int], zoom_pct: float) -> dict[str, object]:
    """Run the road in sumo-gui with the swarm attached; save the view at ``at_s``."""
    import traci

    import sumo_swarm

    with tempfile.TemporaryDirectory(prefix="sumo_swarm_gui_") as tmp:
        cfg = make_road(Path(tmp))
        traci.start(
            [
                "sumo-gui", "-c", str(cfg), "--start", "--quit-on-end",
                "--lateral-resolution", "0.5", "--time-to-teleport", "-1",
                "--collision.action", "warn", "--collision.mingap-factor", "0",
                "--window-size", f"{size[0]},{size[1] + 120}", "--window-pos", "0,0",
                "--no-warnings",
            ]
        )  # fmt: skip
        try:
            swarm = sumo_swarm.attach(traci, cav_type="cav", config=Path(tmp) / "swarm.toml")
            while traci.simulation.getTime() < at_s:
                traci.simulation.step()
            traci.gui.trackVehicle(VIEW, "cav.2")
            traci.gui.setZoom(VIEW, zoom_pct)
            traci.simulation.step()
            out.parent.mkdir(parents=True, exist_ok=True)
            traci.gui.screenshot(VIEW, str(out.resolve()), size[0], size[1])
            traci.simulation.step()  # sumo-gui saves the view at the end of the next step
            summary = swarm.summary()
            swarm.detach()
        finally:
            traci.close()
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=OUT, help="the PNG (default: %(default)s)")
    parser.add_argument("--at", type=float, default=27.0, help="simulated time [s] (default: 27)")
    parser.add_argument("--size", default="1400x520", help="WIDTHxHEIGHT (default: 1400x520)")
    parser.add_argument("--zoom", type=float, default=1500.0, help="sumo-gui zoom [%%] (1500)")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    xvfb = start_display()
    try:
        summary = screenshot(args.out, args.at, (width, height), args.zoom)
    finally:
        if xvfb is not None:
            xvfb.terminate()
            xvfb.wait(timeout=10)
    overtake = summary["overtake"]
    print(
        f"sumo-gui at {args.at:g} s: overtake triggered={overtake['triggered']}, "
        f"collisions={summary['safety']['collisions']} -> {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
