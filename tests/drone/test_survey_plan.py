"""How a survey is cut into work and put back together: tracking blocks, pairs across flight lines, overlapping
submodels, their alignment by shared photos and GPS, the photos' footprints on the ground and the map's grids."""
from __future__ import annotations

import numpy as np
import pytest

from workers.camera import Camera
from workers.drone.evaluation import Sim3
from workers.drone.geo import SimilarityFit
from workers.drone.georef import Georeference, apply
from workers.drone.reconstruction import SparseModel
from workers.drone.surface import Grid
from workers.drone.survey.depthmaps import REFS_PER_TASK, block_size
from workers.drone.survey.ground import (MIN_DSM_TILE, footprint_mask, footprints, most_photos_in_a_tile, plan_ground,
                                         tile_side)
from workers.drone.survey.merge import alignment, merge
from workers.drone.survey.plan import candidate_pairs, plan_survey, tracking_blocks, typical_step


def lawnmower(lines: int, per_line: int, along: float = 15.0, across: float = 28.0) -> np.ndarray:
    """Camera positions (N, 2) of a serpentine survey in flight order."""
    xy = []
    for li in range(lines):
        xs = np.arange(per_line) * along
        for x in (xs if li % 2 == 0 else xs[::-1]):
            xy.append((x, li * across))
    return np.array(xy, np.float64)


def test_blocks_follow_the_flight_and_pairs_tie_the_lines():
    xy = lawnmower(4, 30)
    step = typical_step(xy)
    assert step == pytest.approx(15.0)
    blocks = tracking_blocks(xy, step, block_photos=24)
    assert np.array_equal(np.concatenate(blocks), np.arange(len(xy)))  # every photo once, in flight order
    assert max(len(b) for b in blocks) <= 24
    pairs = {tuple(p) for p in candidate_pairs(xy, step, blocks).tolist()}
    # the photo over the same ground on the next line is matched with it (lines run both ways: 59 - i over i; the
    # turn, 29 then 30, is followed by optical flow)
    assert all((i, 59 - i) in pairs for i in range(29))
    # neighbours along a line that optical flow already joins are not matched again, those in other blocks are
    block = np.zeros(len(xy), int)
    for b, ph in enumerate(blocks):
        block[ph] = b
    assert not any(j == i + 1 and block[i] == block[j] for i, j in pairs)
    assert any(j == i + 1 and block[i] != block[j] for i, j in pairs)


def test_a_large_survey_is_split_into_overlapping_submodels_that_share_photos():
    xy = lawnmower(10, 40)
    xy[17] = np.nan  # a photo without GPS is placed between its neighbours
    plan = plan_survey(xy, photos_per_submodel=100)
    assert len(plan.submodels) == 4 and any("without a GPS" in n for n in plan.notes)
    owner = plan.owner()
    assert (owner >= 0).all()  # every photo in exactly one core
    assert sum(len(s.core) for s in plan.submodels) == len(xy)
    for s in plan.submodels:
        assert set(s.core) <= set(s.members)
    # submodels whose cores touch share photos in both directions (a line's length and a line across)
    for a, sa in enumerate(plan.submodels):
        for b, sb in enumerate(plan.submodels[a + 1:], a + 1):
            near = np.linalg.norm(sa.centre - sb.centre) < 1.5 * np.sqrt(100 * 15.0 * 28.0)
            shared = np.intersect1d(sa.members, sb.members)
            if near:
                assert len(shared) >= 6
                spread = np.ptp(plan.xy[shared], axis=0)
                assert spread.min() > 10.0  # not one line: they fix all seven degrees of a similarity
    small = plan_survey(lawnmower(3, 10), photos_per_submodel=100)
    assert len(small.submodels) == 1 and len(small.submodels[0].members) == 30


def _posed_model(centres: np.ndarray, positions: np.ndarray) -> SparseModel:
    """A registered model of nadir cameras at ``centres`` (N, 3), photo positions ``positions``, ground points below."""
    n = len(centres)
    R = np.tile(np.diag([1.0, -1.0, -1.0]), (n, 1, 1))
    t = -np.einsum("nij,nj->ni", R, centres)
    rng = np.random.default_rng(int(positions[0]))
    points = np.column_stack([rng.uniform(centres[:, 0].min(), centres[:, 0].max(), 200),
                              rng.uniform(centres[:, 1].min(), centres[:, 1].max(), 200), np.zeros(200)])
    m = SparseModel(K=np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), intrinsics=None, scale=1.0, width=640,
                    height=480, frame_index=positions.astype(np.int64), frame_time=[None] * n,
                    frame_name=[f"p{int(i)}" for i in positions], keyframe=np.ones(n, bool), registered=np.ones(n, bool),
                    R=R, t=t, points=points, colors=np.zeros((200, 3), np.uint8), point_error=np.zeros(200),
                    obs_frame=np.zeros(0, np.int64), obs_point=np.zeros(0, np.int64), obs_xy=np.zeros((0, 2)),
                    frame_registration=["map"] * n, frame_inliers=np.full(n, 100), frame_failure=[None] * n)
    m.report = {"media": {}, "tracks": {"count": 0, "observations": 0}, "matcher": {},
                "reprojection_error_px": {"before_ba": {"mean": None}}, "bundle_adjustment": {},
                "intrinsics": {}, "warnings": []}
    return m


def _georef(model: SparseModel, gps: np.ndarray) -> Georeference:
    frames = np.arange(len(model.frame_index))
    fit = SimilarityFit(Sim3(1.0, np.eye(3), np.zeros(3)), np.ones(len(frames), bool), np.zeros(len(frames)), 3.0,
                        False)
    return Georeference(fit.sim, 32632, np.zeros(3), frames, gps, fit, "exif", "test")


def test_submodels_a_few_centimetres_apart_are_aligned_by_their_shared_photos():
    xy = lawnmower(6, 12)
    centres = np.column_stack([xy, np.full(len(xy), 60.0)])
    left = np.flatnonzero(xy[:, 0] < 100)
    right = np.flatnonzero(xy[:, 0] > 60)
    owner = np.where(xy[:, 0] < 80, 0, 1)
    models = {}
    for s, members in ((0, left), (1, right)):
        m = _posed_model(centres[members], members)
        models[s] = (m, _georef(m, centres[members]))
    # submodel 1 placed by its GPS a little off: 4 cm, 0.05 degrees, 0.1 % scale (what noisy GPS fits leave)
    angle = np.radians(0.05)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    apply(models[1][0], Sim3(1.001, turn, np.array([0.04, -0.03, 0.02])), "off")
    sims, report = alignment(models, owner)
    assert report["shared_photos"] == len(np.intersect1d(left, right))
    assert report["before"]["centre_rmse_m"] > 0.03
    assert report["after"]["centre_rmse_m"] < 0.002 and report["after"]["rotation_rmse_deg"] < 0.005
    model, ref, _ = merge(models, owner, np.array([[40.0, 70.0], [130.0, 70.0]]), reference=0)
    assert model.registered.sum() == len(xy) and list(model.frame_index) == list(range(len(xy)))
    err = np.linalg.norm(np.stack([-R.T @ t for R, t in zip(model.R, model.t)]) - centres, axis=1)
    assert err.max() < 0.01  # every photo where it was taken, whichever submodel it came from
    assert len(model.points) == 400 - sum(  # each point once: from the submodel whose centre is nearest
        1 for s, (m, _) in models.items() for p in m.points if (p[0] < 85) != (s == 0))


def test_a_nadir_photos_footprint_is_its_image_on_the_ground():
    cam = Camera("c", np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]), np.diag([1.0, -1.0, -1.0]),
                 np.array([-10.0, 20.0, 60.0]), 640, 480)
    model = _posed_model(np.array([[10.0, 20.0, 60.0]]), np.array([0]))
    model.R[0], model.t[0] = cam.R, cam.t
    model.points[:, :2] = [10.0, 20.0]  # the ground below it at z = 0
    model.K = cam.K
    poly = footprints(model)[0]
    half_w, half_h = 60.0 * 319.5 / 500.0, 60.0 * 239.5 / 500.0  # from the centre to the first and last pixels
    assert poly[:, 0].min() == pytest.approx(10.0 - half_w) and poly[:, 0].max() == pytest.approx(10.0 + half_w)
    assert poly[:, 1].min() == pytest.approx(20.0 - half_h) and poly[:, 1].max() == pytest.approx(20.0 + half_h)
    grid = Grid(-40.0, 60.0, 0.5, 200, 160)
    area = footprint_mask(grid, [poly]).sum() * 0.25
    assert area == pytest.approx(4 * half_w * half_h, rel=0.02)


def test_the_orthophoto_follows_the_photos_resolution_unless_asked_and_a_too_large_map_is_refused():
    xy = lawnmower(2, 4)
    model = _posed_model(np.column_stack([xy, np.full(len(xy), 60.0)]), np.arange(len(xy)))
    model.obs_frame = np.repeat(np.arange(len(xy)), 20)
    model.obs_point = np.tile(np.arange(20), len(xy))
    model.scale = 0.25  # 2560 px photos tracked at 640
    prints = footprints(model)
    plan = plan_ground(model, prints, None, 1.0, "m", 10**9)
    assert plan.photo_gsd == pytest.approx(60.0 / 500.0 * 0.25)  # a native pixel straight below
    assert plan.ortho.gsd == pytest.approx(plan.photo_gsd) and plan.factor == 4  # the DSM at the depth maps' own
    assert "the photos' own" in plan.gsd_reason
    asked = plan_ground(model, prints, 0.10, 1.0, "m", 10**9)
    assert asked.ortho.gsd == 0.10 and "coarser than" in asked.gsd_reason
    with pytest.raises(ValueError, match=r"more than the service's limit of 1,000,000 .*ask for gsd_cm [\d.]+ or more"):
        plan_ground(model, prints, None, 1.0, "m", 1_000_000)


def test_tiles_are_as_large_as_allowed_but_one_for_each_task_the_cluster_runs_at_once():
    """Each tile fuses again the depth maps reaching into it: a small map is one tile on one CPU, as many tiles as CPUs
    on more, never smaller than MIN_DSM_TILE cells, never larger than the bound a task's memory allows."""
    assert tile_side(600, 400, 2048, 1) == 600  # one tile holds it
    side = tile_side(600, 400, 2048, 2)
    assert side == 400 and (600 // side + 1) * 1 == 2  # 2 x 1 tiles: the short side whole, the long side halved
    side = tile_side(3000, 2000, 1024, 2)
    assert side <= 1024 and -(-3000 // side) * -(-2000 // side) >= 2  # the memory bound makes more tiles anyway
    assert tile_side(600, 400, 2048, 10_000) == MIN_DSM_TILE  # never smaller than that
    assert tile_side(100, 80, 2048, 4) == MIN_DSM_TILE  # a map smaller than one tile: one tile
    # 3 x 3 photos 99 cells square, 50 apart: tiles as large as meet at most 4 photos
    boxes = np.array([(50.0 * i, 50.0 * i + 99, 50.0 * k, 50.0 * k + 99) for i in range(3) for k in range(3)])
    assert most_photos_in_a_tile(boxes, 200, 200, 200) == 9
    assert most_photos_in_a_tile(boxes, 200, 200, 100) == most_photos_in_a_tile(boxes, 200, 200, 50) == 4
    side = tile_side(2000, 2000, 2048, 1, lambda s: most_photos_in_a_tile(boxes * 10, 2000, 2000, s) <= 4)
    assert side == 1000 and most_photos_in_a_tile(boxes * 10, 2000, 2000, side) <= 4


def test_depth_map_blocks_even_out_over_the_rounds_of_tasks():
    """A block of references is one task, at most REFS_PER_TASK references; the blocks take no more rounds of the
    fan-out's CPUs than that bound needs, and the slowest CPU makes less than one depth map a round more than an
    even share (30 references in blocks of 6 on 2 CPUs: 3 rounds, 18 maps on one CPU against 15 each)."""
    for refs, cpus in [(30, 2), (28, 2), (1008, 2), (7, 4), (30, 1), (448, 3), (1, 2), (13, 16)]:
        size = block_size(refs, cpus)
        rounds = -(-(-(-refs // size)) // cpus)
        assert 1 <= size <= REFS_PER_TASK and rounds == -(-refs // (cpus * REFS_PER_TASK)), (refs, cpus)
        assert rounds * size - -(-refs // cpus) < rounds, (refs, cpus, size)
    assert block_size(30, 2) == 5 and block_size(30, 1) == 6
