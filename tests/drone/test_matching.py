"""Correspondences: the paper's FAST rule on generated flow with injected outliers, FAST+LK on a
generated image pair, SIFT matching, tracks."""
import cv2
import numpy as np

from workers.drone.features import fast_corners, sift_features, spread
from workers.drone.frames import Frame
from workers.drone.matching import (fast_lk_match, fast_rule_mask, global_motion, global_shift, sampson_distance,
                                    sift_ratio_matches)
from workers.drone.params import ReconstructionParams
from workers.drone import tracks as tracks_module
from workers.drone.tracks import FlowTracker, SiftTracker

K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])


def test_fast_rule_on_generated_flow_with_injected_outliers():
    rng = np.random.default_rng(0)
    corners = rng.uniform(0, 640, (500, 2))  # FAST corners of frame k+1
    good_end = corners[:300] + rng.uniform(-1.0, 1.0, (300, 2))  # flows landing on a corner (<= 1.5 px)
    bad_end = corners[300:400] + rng.uniform(6.0, 10.0, (100, 2)) * rng.choice([-1, 1], (100, 2))
    # An injected outlier must also be far from every other corner to count as one.
    bad_far = np.min(np.linalg.norm(bad_end[:, None] - corners[None], axis=2), axis=1) > 2.0
    mask = fast_rule_mask(np.vstack([good_end, bad_end]), corners, threshold=2.0)
    assert mask[:300].all()
    np.testing.assert_array_equal(mask[300:], ~bad_far)
    assert not fast_rule_mask(np.array([[5.0, 5.0]]), np.zeros((0, 2)), 2.0).any()
    assert fast_rule_mask(np.zeros((0, 2)), corners, 2.0).shape == (0,)


def _texture(seed=0, size=(240, 320)):
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.integers(0, 256, (size[0] // 4, size[1] // 4), dtype=np.uint8), size[::-1],
                     interpolation=cv2.INTER_CUBIC)
    return cv2.GaussianBlur(img, (3, 3), 0.8)


def test_fast_lk_follows_a_known_shift_and_drops_occluded_points():
    g0 = _texture(1)
    dx, dy = 3.25, -2.5
    g1 = cv2.warpAffine(g0, np.array([[1, 0, dx], [0, 1, dy]]), (320, 240), borderMode=cv2.BORDER_REFLECT)
    g1[80:160, 200:300] = _texture(9)[80:160, 200:300]  # a region replaced: flows there are wrong
    pts, _ = fast_corners(g0, 20)
    pts = pts[spread(pts, 6, 800, shape=g0.shape)]
    corners1, _ = fast_corners(g1, 20)
    res = fast_lk_match(g0, g1, pts, corners1, K, rule_threshold=2.0, fb_threshold=1.0, ransac_threshold=1.0,
                        motion=np.array([[1.0, 0, dx], [0, 1.0, dy]]))
    inside = (pts[:, 0] > 20) & (pts[:, 0] < 300) & (pts[:, 1] > 20) & (pts[:, 1] < 220)
    clean = inside & ~((pts[:, 0] > 190) & (pts[:, 0] < 310) & (pts[:, 1] > 70) & (pts[:, 1] < 170))
    occluded = (pts[:, 0] > 205) & (pts[:, 0] < 295) & (pts[:, 1] > 85) & (pts[:, 1] < 155)
    kept = res.inliers
    assert kept[clean].mean() > 0.6
    err = np.linalg.norm(res.end_points[kept & clean] - (pts[kept & clean] + [dx, dy]), axis=1)
    assert np.median(err) < 0.1
    # Flows into the replaced region are mostly caught: the forward-backward check first, then
    # the paper's rule removes part of what the check let through.
    assert res.after_rule[occluded].sum() < res.after_fb[occluded].sum()
    assert (kept & occluded).sum() <= 0.2 * occluded.sum()
    # Each stage keeps a subset of the previous one.
    assert (res.after_fb <= res.converged).all() and (res.after_rule <= res.after_fb).all()
    assert (res.inliers <= res.after_rule).all()


def test_sampson_distance_of_matches_off_their_epipolar_lines():
    # Second camera moved along x: epipolar lines are the image rows of both views, and a match
    # d pixels off its row is d / sqrt(2) from the nearest exact match (half the error each side).
    E = np.array([[0.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # [t]x with t = (1, 0, 0), R = I
    m0 = np.array([[100.0, 50.0], [20.0, 200.0], [300.0, 10.0]])
    m1 = m0 + [[7.0, 0.0], [-3.0, 2.0], [0.5, -0.6]]
    np.testing.assert_allclose(sampson_distance(E, K, m0, m1), np.array([0.0, 2.0, 0.6]) / np.sqrt(2), atol=1e-9)


def test_fast_lk_match_marks_flows_only_the_rule_rejected_as_consistent():
    g0 = _texture(4)
    dx, dy = 2.5, 1.75
    g1 = cv2.warpAffine(g0, np.array([[1, 0, dx], [0, 1, dy]]), (320, 240), borderMode=cv2.BORDER_REFLECT)
    pts, _ = fast_corners(g0, 20)
    pts = pts[spread(pts, 6, 800, shape=g0.shape)]
    corners1, _ = fast_corners(g1, 20)
    hole = (corners1[:, 0] > 80) & (corners1[:, 0] < 180)  # frame k+1 "misses" every corner here
    res = fast_lk_match(g0, g1, pts, corners1[~hole], K, motion=np.array([[1.0, 0, dx], [0, 1.0, dy]]))
    in_hole = (pts[:, 0] + dx > 85) & (pts[:, 0] + dx < 175) & (pts[:, 1] > 20) & (pts[:, 1] < 220)
    assert in_hole.sum() > 50
    assert not res.after_rule[in_hole].any()
    # Their flows are right: they fit the pair's geometry, unlike what the rule says.
    assert res.consistent[in_hole & res.after_fb].mean() > 0.9
    assert (res.inliers <= res.consistent).all() and (res.consistent <= res.after_fb).all()


def _shifted_frames(n: int, step: tuple[float, float]) -> list[Frame]:
    g0 = _texture(5)
    frames = []
    for i in range(n):
        A = np.array([[1.0, 0, i * step[0]], [0, 1.0, i * step[1]]])
        g = cv2.warpAffine(g0, A, (320, 240), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        frames.append(Frame(i, i / 25, f"f{i}", cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), g))
    return frames


def test_flow_tracker_bridges_a_frame_where_the_rule_rejects_a_track(monkeypatch):
    """FAST misses every corner of a region in frame 2 only. Without gaps the tracks there end
    and new ones start in frame 3; with a gap of one frame the same tracks go on, unrecorded in
    frame 2."""
    real = tracks_module.fast_corners_adaptive
    frames = _shifted_frames(4, (1.5, 1.0))
    region = (120.0, 200.0, 80.0, 160.0)  # x0, x1, y0, y1 in frame 2

    def corners_missing_in_frame_2(gray, threshold, min_count):
        pts = real(gray, threshold, min_count)
        if gray is frames[2].gray:
            x0, x1, y0, y1 = region
            pts = pts[~((pts[:, 0] > x0 - 5) & (pts[:, 0] < x1 + 5) & (pts[:, 1] > y0 - 5) & (pts[:, 1] < y1 + 5))]
        return pts

    monkeypatch.setattr(tracks_module, "fast_corners_adaptive", corners_missing_in_frame_2)

    def run(gap: int):
        tracker = FlowTracker(K, ReconstructionParams(max_features=600, max_track_gap=gap))
        for f in frames:
            tracker.add(f)
        ts = tracker.result()
        xy1 = ts.obs_xy[ts.frame_slice(1)] + [1.5, 1.0]  # where frame 1's tracks are in frame 2
        x0, x1, y0, y1 = region
        inside = (xy1[:, 0] > x0) & (xy1[:, 0] < x1) & (xy1[:, 1] > y0) & (xy1[:, 1] < y1)
        ids = {f: set(ts.obs_track[ts.frame_slice(f)].tolist()) for f in range(4)}
        return set(ts.obs_track[ts.frame_slice(1)][inside].tolist()), ids, [pair.bridged for pair in ts.pairs]

    tracked, ids, bridged = run(0)
    assert len(tracked) > 30
    assert not tracked & ids[2] and not tracked & ids[3]
    assert bridged == [0, 0, 0]
    tracked, ids, bridged = run(1)
    assert not tracked & ids[2]
    assert len(tracked & ids[3]) > 0.8 * len(tracked)
    assert bridged[1] >= len(tracked)  # the pair (1, 2) bridged at least those tracks


def test_global_motion_estimates_shift_and_half_turn():
    g0 = _texture(2, (480, 640))
    shift, peak = global_shift(g0, np.roll(g0, (7, -12), axis=(0, 1)))
    np.testing.assert_allclose(shift, [-12, 7], atol=0.5)
    assert peak > 0.3
    g1 = cv2.rotate(g0, cv2.ROTATE_180)
    A = global_motion(g0, g1)
    assert A is not None
    p = np.array([[100.0, 50.0], [400.0, 300.0]])
    np.testing.assert_allclose(p @ A[:, :2].T + A[:, 2], [639, 479] - p, atol=3.0)


def test_sift_ratio_matches_known_correspondence():
    g0 = _texture(3, (240, 320))
    g1 = np.roll(g0, 10, axis=1)
    k0, d0 = sift_features(g0)
    k1, d1 = sift_features(g1)
    m = sift_ratio_matches(d0, d1, 0.7)
    assert len(m) > 50
    ok = np.linalg.norm(k1[m[:, 1]] - (k0[m[:, 0]] + [10, 0]), axis=1) < 1.0
    inner = (k0[m[:, 0], 0] > 20) & (k0[m[:, 0], 0] < 290)
    assert ok[inner].mean() > 0.95


def test_sift_keypoints_lie_on_the_features_they_find():
    # Dark Gaussian blobs at known sub-pixel centres (pixel centres at integers): SIFT finds each at its centre.
    yy, xx = np.mgrid[0:240, 0:320].astype(np.float64)
    rng = np.random.default_rng(0)
    img = np.full((240, 320), 128.0)
    centres = []
    for cy in range(30, 220, 40):
        for cx in range(30, 300, 40):
            c = (cx + rng.uniform(-0.5, 0.5), cy + rng.uniform(-0.5, 0.5))
            centres.append(c)
            img -= 90 * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / 18.0)
    k, _ = sift_features(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    c = np.array(centres)
    nearest = c[np.argmin(np.linalg.norm(k[:, None] - c[None], axis=2), axis=1)]
    err = k - nearest
    assert len(k) >= len(c)
    assert np.all(np.abs(np.median(err, axis=0)) < 0.05)


def test_sift_keypoints_agree_between_a_photo_and_its_half_turn():
    # Two flight lines flown in opposite directions: one photo's axes are the other's turned half a turn.
    g0 = _texture(5, (240, 320))
    g1 = np.ascontiguousarray(g0[::-1, ::-1])
    k0, d0 = sift_features(g0)
    k1, d1 = sift_features(g1)
    m = sift_ratio_matches(d0, d1, 0.7)
    assert len(m) > 50
    d = k1[m[:, 1]] - ([319, 239] - k0[m[:, 0]])
    d = d[np.linalg.norm(d, axis=1) < 2]
    assert np.all(np.abs(np.median(d, axis=0)) < 0.1)


def test_trackers_build_tracks_on_the_flight(flight):
    p = ReconstructionParams(max_features=400)
    frames = [Frame(i, i / 25, f"f{i}", img, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
              for i, img in enumerate(flight.frames[:6])]
    for tracker in (FlowTracker(flight.K, p), SiftTracker(flight.K, p)):
        for f in frames:
            tracker.add(f)
        ts = tracker.result()
        assert ts.n_frames == 6 and ts.n_tracks > 100
        assert np.all(np.diff(ts.obs_frame) >= 0)
        # No track has two observations in one frame.
        key = ts.obs_track * 10 + ts.obs_frame
        assert len(np.unique(key)) == len(key)
        assert all(s.inlier_ratio > 0.5 for s in ts.pairs)
        # Observations agree with the true geometry: project each track's ray...
        a, b = ts.frame_slice(0), ts.frame_slice(1)
        common, ia, ib = np.intersect1d(ts.obs_track[a], ts.obs_track[b], return_indices=True)
        c0, c1 = flight.cameras[0], flight.cameras[1]
        Rrel = c1.R @ c0.R.T
        trel = c1.t - Rrel @ c0.t
        E = np.array([[0, -trel[2], trel[1]], [trel[2], 0, -trel[0]], [-trel[1], trel[0], 0]]) @ Rrel
        x0 = np.column_stack([ts.obs_xy[a][ia], np.ones(len(ia))]) @ np.linalg.inv(flight.K).T
        x1 = np.column_stack([ts.obs_xy[b][ib], np.ones(len(ib))]) @ np.linalg.inv(flight.K).T
        l1 = x0 @ E.T
        dist = np.abs(np.einsum("ij,ij->i", x1, l1)) / np.linalg.norm(l1[:, :2], axis=1) * flight.K[0, 0]
        assert np.median(dist) < 0.5


def test_survey_match_features_from_a_reduced_copy_lie_on_the_full_size_features():
    # A 1280 x 960 working image: SIFT looks at a copy half as large, and the keypoints come back in the full size's
    # pixels (pixel centres at integers), where the optical flow measures them again.
    from workers.drone.survey.sparse import MATCH_MAX_SIDE, match_features

    h, w = 960, 1280
    assert max(h, w) > MATCH_MAX_SIDE
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    rng = np.random.default_rng(1)
    img = np.full((h, w), 128.0)
    centres = []
    for cy in range(60, h - 40, 80):
        for cx in range(60, w - 40, 80):
            c = (cx + rng.uniform(-1, 1), cy + rng.uniform(-1, 1))
            centres.append(c)
            img -= 90 * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / 72.0)
    k, d = match_features(np.clip(np.rint(img), 0, 255).astype(np.uint8), 4000)
    assert len(k) == len(d) >= len(centres)
    c = np.array(centres)
    dist = np.linalg.norm(k[:, None] - c[None], axis=2)
    err = k - c[np.argmin(dist, axis=1)]
    assert np.all(np.abs(np.median(err, axis=0)) < 0.15)  # no offset from the copy's scale
    assert np.median(dist.min(axis=1)) < 0.5
