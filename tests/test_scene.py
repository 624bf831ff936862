"""The paper's scene (Figure 6) is placed as configured; SUMO inputs are well formed."""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET

from sumo_swarm.config import load_scenario
from sumo_swarm.sim.scene import build_scene, write_sumo_inputs


def test_paper_scene_layout(paper_path):
    scene = build_scene(load_scenario(paper_path))
    by_id = {v.id: v for v in scene.vehicles}
    assert scene.cav_ids == ("cav0", "cav1", "cav2", "cav3", "cav4", "cav5")
    assert [by_id[c].front_m for c in scene.cav_ids] == [300, 285, 270, 255, 240, 225]
    assert all(by_id[c].lane == 1 for c in scene.cav_ids)
    assert scene.target_id == "hv_target"
    # 10 m from the leader's front to the target's rear
    assert by_id["hv_target"].front_m - by_id["hv_target"].length_m - 300 == 10
    # five upstream HVs per lane, 25 m apart, behind the last vehicle of each lane
    for lane, last_rear in ((0, 235.0), (1, 220.0), (2, 250.0)):
        ups = sorted(
            (v for v in scene.vehicles if v.role == "upstream" and v.lane == lane),
            key=lambda v: -v.front_m,
        )
        assert len(ups) == 5
        assert ups[0].front_m == last_rear - 25.0
        assert all(a.front_m - a.length_m - b.front_m == 25.0 for a, b in itertools.pairwise(ups))
    # no two vehicles of one lane overlap
    for lane in range(3):
        spans = sorted(
            (v.front_m - v.length_m, v.front_m) for v in scene.vehicles if v.lane == lane
        )
        assert all(a[1] <= b[0] for a, b in itertools.pairwise(spans))


def test_inputs_differ_only_in_the_cav_type(paper_path, tmp_path):
    sc = load_scenario(paper_path)
    texts = {}
    for controller in ("cacc", "sumo-cacc", "sumo-lc", "swarm"):
        cfg, _ = write_sumo_inputs(sc, controller, tmp_path / controller)
        ET.parse(cfg)
        routes = ET.parse(cfg.parent / "routes.rou.xml").getroot()
        texts[controller] = [
            ET.tostring(e) for e in routes if not (e.tag == "vType" and e.get("id") == "cav")
        ]
        cav_type = routes.find("vType[@id='cav']")
        assert cav_type is not None
    assert texts["cacc"] == texts["sumo-cacc"] == texts["sumo-lc"] == texts["swarm"]
    cacc_type = ET.parse(tmp_path / "sumo-cacc" / "routes.rou.xml").find("vType[@id='cav']")
    assert cacc_type.get("carFollowModel") == "CACC"
