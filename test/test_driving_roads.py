"""The driving map's geometry against docs/original.md §3 in metres, and lane classification of placed poses."""
import math

import numpy as np
import pytest

from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.roads import DrivingMap, LanePosition, LineKind, classify_on_road

EAST, NORTH, WEST, SOUTH = 0.0, math.pi / 2, math.pi, -math.pi / 2


@pytest.fixture(scope="module")
def dmap():
    return DrivingMap()


def test_four_buildings_of_80_by_45_m_at_the_original_centres(dmap):
    # 800 x 450 px boxes centred at (365, 200), (365, 800), (1385, 200), (1385, 800) px.
    centres = sorted((b.x, b.y) for b in dmap.buildings)
    assert centres == [(36.5, 20.0), (36.5, 80.0), (138.5, 20.0), (138.5, 80.0)]
    assert {(b.half_x, b.half_y) for b in dmap.buildings} == {(40.0, 22.5)}
    np.testing.assert_allclose(dmap.buildings[0].corners, [[-3.5, -2.5], [76.5, -2.5], [76.5, 42.5], [-3.5, 42.5]])


def test_roads_lanes_and_walkways(dmap):
    vertical, horizontal = dmap.roads
    assert (vertical.start, vertical.end, vertical.lanes) == ((87.5, 0.0), (87.5, 100.0), 2)
    assert (horizontal.start, horizontal.end, horizontal.lanes) == ((0.0, 50.0), (170.0, 50.0), 1)
    assert dmap.crossing == (87.5, 50.0)
    # Lane lines at k·3.5 m, k = −n..n: edges, centre line, inner lines.
    vertical_lines = sorted((line.x1, line.kind) for line in dmap.lane_lines if line.road == 0)
    assert vertical_lines == [(80.5, LineKind.EDGE), (84.0, LineKind.INNER), (87.5, LineKind.CENTRE),
                              (91.0, LineKind.INNER), (94.5, LineKind.EDGE)]
    horizontal_lines = sorted((line.y1, line.kind) for line in dmap.lane_lines if line.road == 1)
    assert horizontal_lines == [(46.5, LineKind.EDGE), (50.0, LineKind.CENTRE), (53.5, LineKind.EDGE)]
    # Walkway lines at ±(n + 1)·3.5 m.
    lines = dmap.walkway_lines
    assert sorted(lines[:2, 0]) == [77.0, 98.0] and sorted(lines[2:, 1]) == [43.0, 57.0]
    # Walkway stretches stop at the other road's carriageway.
    stretches = sorted((s.road, s.side, s.s_min, s.s_max) for s in dmap.walkway_segments)
    assert stretches[:4] == [(0, -1, 0.0, 46.5), (0, -1, 53.5, 100.0), (0, 1, 0.0, 46.5), (0, 1, 53.5, 100.0)]
    assert stretches[4:] == [(1, -1, 0.0, 80.5), (1, -1, 94.5, 170.0), (1, 1, 0.0, 80.5), (1, 1, 94.5, 170.0)]


def test_lane_centres_drive_on_the_right(dmap):
    centres = {(c.road, c.sign, c.k): (c.x1, c.y1, c.x2, c.y2) for c in dmap.lane_centres}
    assert centres[(0, 1, 0)] == (89.25, 0.0, 89.25, 100.0)       # northbound: east of the centre line
    assert centres[(0, 1, 1)] == (92.75, 0.0, 92.75, 100.0)
    assert centres[(0, -1, 0)] == (85.75, 100.0, 85.75, 0.0)      # southbound: west of it
    assert centres[(1, 1, 0)] == (0.0, 48.25, 170.0, 48.25)       # eastbound: south of it
    assert centres[(1, -1, 0)] == (170.0, 51.75, 0.0, 51.75)
    assert len(centres) == 6


def test_thirty_spawn_spots_five_per_lane_9_m_apart_heading_into_the_map(dmap):
    spots = dmap.spawn_spots
    assert len(spots) == 30
    by_lane: dict = {}
    for spot in spots:
        by_lane.setdefault((spot.road, spot.end, spot.lane), []).append(spot)
    assert len(by_lane) == 6 and {len(v) for v in by_lane.values()} == {5}
    west = sorted(s.x for s in by_lane[(1, 2, 0)])
    assert west == pytest.approx([4.5, 13.5, 22.5, 31.5, 40.5])
    assert {(s.y, s.yaw) for s in by_lane[(1, 2, 0)]} == {(48.25, 0.0)}
    north = by_lane[(0, 1, 1)]
    assert {s.x for s in north} == {82.25} and max(s.y for s in north) == pytest.approx(95.5)
    assert {round(s.yaw, 9) for s in north} == {round(SOUTH, 9)}
    for spot in spots:   # every spot is in its right lane, inside the map
        assert dmap.classify(spot.x, spot.y, spot.yaw) == LanePosition.RIGHT_LANE
        assert dmap.inside(spot.x, spot.y)


def test_destinations_are_the_four_road_ends(dmap):
    np.testing.assert_allclose(dmap.destinations, [[87.5, 0.0], [87.5, 100.0], [0.0, 50.0], [170.0, 50.0]])
    assert [dmap.road_of_end(i) for i in range(4)] == [(0, -1), (0, 1), (1, -1), (1, 1)]
    assert dmap.nearest_end(169.0, 51.0) == 3


@pytest.mark.parametrize("x,y,yaw,goal,expected", [
    (89.25, 20.0, NORTH, None, LanePosition.RIGHT_LANE),        # northbound, east half
    (85.75, 20.0, NORTH, None, LanePosition.OPPOSING_LANE),     # northbound in the southbound lanes
    (85.75, 20.0, SOUTH, None, LanePosition.RIGHT_LANE),
    (60.0, 48.25, EAST, None, LanePosition.RIGHT_LANE),
    (60.0, 51.75, EAST, None, LanePosition.OPPOSING_LANE),
    (60.0, 51.75, WEST, None, LanePosition.RIGHT_LANE),
    (94.9, 20.0, NORTH, None, LanePosition.RIGHT_LANE),         # 0.4 m past the edge: still on the road ...
    (95.0, 20.0, NORTH, None, LanePosition.OFF_ROAD),           # ... 5 px past it: off road
    (60.0, 45.9, EAST, None, LanePosition.OFF_ROAD),
    (60.0, 30.0, EAST, None, LanePosition.OFF_ROAD),            # between buildings
    (89.25, 50.0, NORTH, None, LanePosition.RIGHT_LANE),        # in the crossing: the better road counts
    (89.25, 52.0, EAST, None, LanePosition.OPPOSING_LANE),      # crossing eastbound north of the centre line
    (85.75, -0.9, SOUTH, None, LanePosition.RIGHT_LANE),        # within 10 px of the road end
    (85.75, -1.1, SOUTH, None, LanePosition.OVER_ROAD),         # past the south end
    (89.25, -1.1, SOUTH, 0, LanePosition.AT_GOAL),              # ... which is its destination
    (89.25, -1.1, SOUTH, 1, LanePosition.OVER_ROAD),            # ... which is not
    (171.5, 48.25, EAST, 3, LanePosition.AT_GOAL),
    (181.0, 48.25, EAST, 3, LanePosition.OVER_ROAD),            # past the end but 11 m from it (radius 100 px)
    (-1.5, 51.75, WEST, 3, LanePosition.OVER_ROAD),             # past the wrong end
])
def test_lane_position_of_placed_poses(dmap, x, y, yaw, goal, expected):
    assert dmap.classify(x, y, yaw, goal) == expected


def test_inlined_classification_agrees_with_the_per_road_rule(dmap):
    rng = np.random.default_rng(0)
    m = dmap.config
    for x, y, yaw in zip(rng.uniform(-5, 175, 2000), rng.uniform(-5, 105, 2000), rng.uniform(-4, 4, 2000)):
        per_road = min(classify_on_road(road, x, y, yaw, m.off_road_margin, m.end_margin)[0] for road in dmap.roads)
        assert dmap.classify(x, y, yaw) == per_road


def test_a_different_map_config_moves_everything():
    config = DrivingConfig.from_mapping({"map": {"vertical_road_x": 86.0, "vertical_lanes": 1}}).map
    dmap = DrivingMap(config)
    assert dmap.roads[0].start == (86.0, 0.0) and dmap.roads[0].half_width == 3.5
    assert len(dmap.spawn_spots) == 20
    assert dmap.classify(87.75, 20.0, NORTH) == LanePosition.RIGHT_LANE
    assert dmap.classify(91.0, 20.0, NORTH) == LanePosition.OFF_ROAD
