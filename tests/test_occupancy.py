"""Tests for vtlearn.active.occupancy: log-odds updates (eq. 5.7), entropy (eq. 5.6) and expected
information gain (eq. 5.8), with a naive dense-sampling traversal and a one-at-a-time loop as references."""

import numpy as np
import pytest

from vtlearn.active.occupancy import OccupancyGrid, binary_entropy, logit


def dense_sampling_cells(grid, origin, direction, max_range, n=100_001):
    """Naive reference: sample the ray densely and list the distinct cells in order."""
    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    ts = np.linspace(0.0, max_range, n)[:-1]
    cells = np.floor((origin + ts[:, None] * direction - grid.origin) / grid.resolution).astype(int)
    inside = ((cells >= 0) & (cells < np.array(grid.shape))).all(axis=1)
    flat = np.ravel_multi_index(cells[inside].T, grid.shape)
    if flat.size == 0:
        return []
    return flat[np.r_[True, flat[1:] != flat[:-1]]].tolist()


def test_entropy_of_unknown_grid_is_n_ln2():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.01, (4, 5, 6))
    assert grid.entropy() == pytest.approx(120 * np.log(2.0), rel=1e-12)
    assert np.allclose(grid.probabilities(), 0.5)


def test_entropy_matches_binary_entropy_formula():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.01, (2, 2, 2))
    p = np.array([0.5, 0.7, 0.4, 0.9, 0.12, 0.97, 0.3, 0.6]).reshape(2, 2, 2)
    grid.log_odds[:] = logit(p)
    ref = -(p * np.log(p) + (1 - p) * np.log(1 - p)).sum()
    assert grid.entropy() == pytest.approx(ref, rel=1e-12)
    assert binary_entropy([0.0, 1.0]).tolist() == [0.0, 0.0]


def test_hit_ray_marks_end_cell_occupied_and_cells_before_free():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (6, 3, 3))
    # Along the x axis through the centres of cells (i, 1, 1); the surface point lies in cell 4.
    grid.insert_points([[-0.05, 0.15, 0.15]], [[0.45, 0.15, 0.15]])
    p = grid.probabilities()
    assert np.allclose(p[:4, 1, 1], 0.4)  # one miss: p_miss
    assert p[4, 1, 1] == pytest.approx(0.7)  # one hit: p_hit
    assert p[5, 1, 1] == pytest.approx(0.5)  # behind the surface: untouched
    untouched = np.ones(grid.shape, bool)
    untouched[:5, 1, 1] = False
    assert np.allclose(p[untouched], 0.5)


def test_ray_without_return_misses_up_to_max_range():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (6, 1, 1))
    grid.insert_rays([[-0.05, 0.05, 0.05]], [[1.0, 0.0, 0.0]], [0.3], [False])
    p = grid.probabilities()[:, 0, 0]
    assert np.allclose(p[:3], 0.4) and np.allclose(p[3:], 0.5)


def test_log_odds_are_clamped():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (3, 1, 1))
    for _ in range(30):
        grid.insert_points([[-0.05, 0.05, 0.05]], [[0.25, 0.05, 0.05]])
    p = grid.probabilities()[:, 0, 0]
    assert p[0] == pytest.approx(0.1192) and p[1] == pytest.approx(0.1192)
    assert p[2] == pytest.approx(0.971)


def test_one_update_per_cell_per_scan_and_hit_wins():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (4, 1, 1))
    # Two identical rays in one scan update each cell once; a second ray ending earlier in cell 1 makes
    # cell 1 a hit even though the first ray passes through it as a miss.
    o = [[-0.05, 0.05, 0.05]] * 3
    e = [[0.35, 0.05, 0.05], [0.35, 0.05, 0.05], [0.15, 0.05, 0.05]]
    grid.insert_points(o, e)
    p = grid.probabilities()[:, 0, 0]
    assert np.allclose(p, [0.4, 0.7, 0.4, 0.7])


def test_dda_matches_dense_sampling_reference():
    grid = OccupancyGrid([-0.1, 0.0, 0.2], 0.05, (7, 5, 4))
    rng = np.random.default_rng(0)
    for i in range(60):
        o = rng.uniform([-0.3, -0.2, 0.0], [0.5, 0.45, 0.6])
        d = rng.normal(size=3)
        if i % 4 == 0:
            d[rng.integers(3)] = 0.0  # axis-parallel in one coordinate
        if i % 9 == 0:
            d[:] = 0.0
            d[rng.integers(3)] = rng.choice([-1.0, 1.0])  # along a grid axis
        d /= np.linalg.norm(d)
        r = rng.uniform(0.0, 0.8)
        trav = grid.traverse(o[None], d[None], r)
        assert trav.cell_index.tolist() == dense_sampling_cells(grid, o, d, r), f"ray {i}"
        assert (trav.ray_index == 0).all()


def test_dda_batch_equals_single_rays_and_is_ray_major():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (5, 5, 5))
    rng = np.random.default_rng(3)
    o = rng.uniform(-0.2, 0.7, (20, 3))
    d = rng.normal(size=(20, 3))
    trav = grid.traverse(o, d, 1.0)
    assert (np.diff(trav.ray_index) >= 0).all()
    for i in range(20):
        single = grid.traverse(o[i : i + 1], d[i : i + 1], 1.0)
        assert trav.cell_index[trav.ray_index == i].tolist() == single.cell_index.tolist()


def test_diagonal_through_corners_is_six_connected():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 1.0, (4, 4, 4))
    trav = grid.traverse([[0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]], 10.0)
    cells = np.stack(np.unravel_index(trav.cell_index, grid.shape), axis=1)
    assert cells[0].tolist() == [0, 0, 0] and cells[-1].tolist() == [3, 3, 3]
    assert (np.abs(np.diff(cells, axis=0)).sum(axis=1) == 1).all()
    assert len(cells) == 10  # 1 + 3 crossings on each axis


def test_expected_measurement_stops_at_believed_occupied_cell():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (6, 1, 1))
    grid.log_odds[3, 0, 0] = 2.0
    ranges, hit = grid.expected_measurement(
        [[-0.05, 0.05, 0.05], [0.55, 0.05, 0.05]], [[1, 0, 0], [1, 0, 0]], 1.0
    )
    assert hit.tolist() == [True, False]
    assert ranges[0] == pytest.approx(0.4)  # middle of cell 3 seen from x = -0.05
    assert ranges[1] == pytest.approx(1.0)


def hypothetical_gain_loop(grid, origins, directions, max_range, action_index):
    """One action at a time: predict, copy the grid, integrate, compare entropies."""
    gains = []
    h0 = grid.entropy()
    for a in range(int(action_index.max()) + 1):
        sel = action_index == a
        ranges, hit = grid.expected_measurement(origins[sel], directions[sel], max_range)
        post = grid.copy()
        post.insert_rays(origins[sel], directions[sel], ranges, hit)
        gains.append(h0 - post.entropy())
    return np.array(gains)


def test_batched_information_gain_equals_one_at_a_time_loop():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.05, (12, 10, 8))
    rng = np.random.default_rng(7)
    # A partly explored belief: an occupied blob plus free space from some earlier scans.
    centers = grid.cell_centers().reshape(*grid.shape, 3)
    blob = np.linalg.norm(centers - [0.3, 0.25, 0.2], axis=-1) < 0.12
    o = rng.uniform(-0.2, 0.8, (40, 3))
    e = rng.uniform(0.0, 0.5, (40, 3))
    grid.insert_points(o, e)
    grid.log_odds[blob] = 1.5
    before = grid.log_odds.copy()
    n_act, k = 25, 6
    origins = np.repeat(rng.uniform(-0.3, 0.9, (n_act, 3)), k, axis=0) + rng.normal(0, 0.02, (n_act * k, 3))
    directions = np.repeat([0.3, 0.25, 0.2] - origins[::k], k, axis=0) + rng.normal(0, 0.1, (n_act * k, 3))
    action_index = np.repeat(np.arange(n_act), k)
    batched = grid.expected_information_gain(origins, directions, 1.2, action_index)
    looped = hypothetical_gain_loop(
        grid, origins, directions / np.linalg.norm(directions, axis=1)[:, None], 1.2, action_index
    )
    assert np.array_equal(grid.log_odds, before)  # the grid is unchanged
    assert batched.shape == (n_act,)
    assert np.allclose(batched, looped, atol=1e-9)
    assert (batched > 0).any()


def test_batched_gain_chunked_and_unsorted_actions_match_per_action_calls():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (5, 5, 5))
    rng = np.random.default_rng(2)
    o = rng.uniform(-0.3, 0.8, (30, 3))
    d = rng.normal(size=(30, 3))
    action_index = rng.integers(0, 7, 30)
    full = grid.expected_information_gain(o, d, 2.0, action_index, n_actions=9)
    grid.max_buffer_cells = 2 * grid.n_cells  # two actions per chunk
    chunked = grid.expected_information_gain(o, d, 2.0, action_index, n_actions=9)
    single = [
        grid.expected_information_gain(o[action_index == a], d[action_index == a], 2.0)[0:].sum()
        if (action_index == a).any()
        else 0.0
        for a in range(9)
    ]
    assert np.allclose(full, chunked)
    assert full[7] == 0.0 and full[8] == 0.0
    # One action's rays taken together gain no more than the sum of the rays taken alone.
    assert (full <= np.array(single) + 1e-12).all()


def test_largest_unexplored_view_wins():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (10, 10, 10))
    # Everything with x < 0.5 has been explored (free); the x >= 0.5 half is unknown.
    grid.log_odds[:5] = logit(0.1192)
    ys, zs = np.meshgrid(np.linspace(0.15, 0.85, 4), np.linspace(0.15, 0.85, 4))
    pad = np.stack([np.zeros(16), ys.ravel(), zs.ravel()], axis=1)
    # Action 0 looks along +x from the explored side at x = 0.1 over 0.3 m (all explored),
    # action 1 looks along +x from x = 0.3 over 0.6 m (half unexplored),
    # action 2 looks along -x from x = 1.05 over 0.6 m (all unexplored).
    origins = np.concatenate([pad + [0.1, 0, 0], pad + [0.3, 0, 0], pad + [1.05, 0, 0]])
    directions = np.concatenate([np.tile([1.0, 0, 0], (16, 1))] * 2 + [np.tile([-1.0, 0, 0], (16, 1))])
    gains = grid.expected_information_gain(origins, directions, 0.6, np.repeat(np.arange(3), 16))
    assert int(np.argmax(gains)) == 2
    assert gains[2] > gains[1] > gains[0]


def test_bad_input_raises_value_error():
    with pytest.raises(ValueError, match="resolution"):
        OccupancyGrid([0, 0, 0], 0.0, (2, 2, 2))
    with pytest.raises(ValueError, match="shape"):
        OccupancyGrid([0, 0, 0], 0.1, (2, 0, 2))
    with pytest.raises(ValueError, match="origin"):
        OccupancyGrid([0, np.nan, 0], 0.1, (2, 2, 2))
    with pytest.raises(ValueError, match="p_hit"):
        OccupancyGrid([0, 0, 0], 0.1, (2, 2, 2), p_hit=0.4)
    with pytest.raises(ValueError, match="upper"):
        OccupancyGrid.from_bounds([0, 0, 0], [1, 0, 1])
    grid = OccupancyGrid([0, 0, 0], 0.1, (2, 2, 2))
    with pytest.raises(ValueError, match="directions"):
        grid.traverse([[0, 0, 0]], [[0, 0, 0]], 1.0)
    with pytest.raises(ValueError, match="origins"):
        grid.traverse(np.zeros((0, 3)), np.zeros((0, 3)), 1.0)
    with pytest.raises(ValueError, match="max_range"):
        grid.traverse([[0, 0, 0]], [[1, 0, 0]], -1.0)
    with pytest.raises(ValueError, match="action_index"):
        grid.expected_information_gain([[0, 0, 0]], [[1, 0, 0]], 1.0, [0.5])
    with pytest.raises(ValueError, match="hit"):
        grid.insert_rays([[0, 0, 0]], [[1, 0, 0]], 1.0, [True, False])
    with pytest.raises(ValueError, match="stop_mask"):
        grid.traverse([[0, 0, 0]], [[1, 0, 0]], 1.0, stop_mask=np.zeros((3, 3, 3), bool))


def test_from_bounds_covers_box():
    grid = OccupancyGrid.from_bounds([0, 0, 0], [0.2, 0.1, 0.05], cells_per_axis=20)
    assert grid.shape == (20, 10, 5)
    assert grid.resolution == pytest.approx(0.01)
    assert np.allclose(grid.upper, [0.2, 0.1, 0.05])


def test_probabilistic_gain_matches_outcome_enumeration():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.1, (6, 2, 2))
    grid.log_odds[:, 0, 0] = [-1.0, 0.0, 0.8, 0.0, 2.0, -0.5]
    o, d = np.array([[-0.05, 0.05, 0.05]]), np.array([[1.0, 0.0, 0.0]])
    gain = grid.expected_information_gain(o, d, 0.7, mode="probabilistic")[0]
    # Reference: enumerate where the ray stops (cell i with prob p_i * prod_{j<i}(1 - p_j)) or not at all.
    p = grid.probabilities()[:, 0, 0]
    h0, expected, reach = grid.entropy(), 0.0, 1.0
    for i in range(6):
        post = grid.copy()
        post.insert_rays(o, d, [0.1 * i + 0.1], [True])  # ends in the middle of cell i
        expected += reach * p[i] * (h0 - post.entropy())
        reach *= 1 - p[i]
    post = grid.copy()
    post.insert_rays(o, d, [0.7], [False])
    expected += reach * (h0 - post.entropy())
    assert gain == pytest.approx(expected, rel=1e-10)
    with pytest.raises(ValueError, match="mode"):
        grid.expected_information_gain(o, d, 0.7, mode="oracle")


def test_probability_helpers_refuse_out_of_range():
    # logit needs (0, 1); the entropy summand of eq. 5.6 is defined on [0, 1]
    for bad in (1.5, 0.0, 1.0, np.nan, [0.3, -0.1]):
        with pytest.raises(ValueError, match="p: probabilities must lie in"):
            logit(bad)
    for bad in (2.0, -0.5, np.nan, [0.5, np.inf]):
        with pytest.raises(ValueError, match="p: probabilities must lie in"):
            binary_entropy(bad)
    assert logit(0.5) == 0.0
    assert binary_entropy(0.5) == pytest.approx(np.log(2.0))


def test_cell_helpers_and_counts_name_bad_arguments():
    grid = OccupancyGrid([0, 0, 0], 0.1, (4, 4, 4))
    assert grid.flat_index([[1, 2, 3]]).tolist() == [(1 * 4 + 2) * 4 + 3]
    with pytest.raises(ValueError, match="cells: .*outside the grid"):
        grid.flat_index([[4, 0, 0]])
    with pytest.raises(ValueError, match="cells: expected"):
        grid.flat_index([1, 2])
    with pytest.raises(ValueError, match="cells: expected"):
        grid.cell_centers([[np.nan, 0, 0]])
    np.testing.assert_allclose(grid.cell_centers([[-1, 0, 0]]), [[-0.05, 0.05, 0.05]])  # outside is fine
    with pytest.raises(ValueError, match="margin"):
        grid.known_fraction(2.0)
    with pytest.raises(ValueError, match="n_actions"):
        grid.expected_information_gain([[0, 0, 0]], [[1, 0, 0]], 1.0, [0], 2.5)


def test_bench_occupancy_tiny_prints_ratio_and_writes_json(tmp_path, capsys):
    import json

    from vtlearn.cli import main

    out = tmp_path / "occ.json"
    assert main(["bench", "occupancy", "--cells", "12", "--actions", "6", "--prior-touches", "1",
                 "--repeats", "1", "--loop-actions", "2", "--no-octomap", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "x batched" in text and f"wrote {out}" in text
    rows = json.loads(out.read_text())["rows"]
    assert rows[0]["x batched"] == 1.0 and rows[1]["x batched"] is None  # CPU time is not a wall time
    assert rows[2]["x batched"] == pytest.approx(rows[2]["seconds"] / rows[0]["seconds"])
