import numpy as np
import pytest

from holodata import metrics as M


def test_range_image_metrics_hand_computed():
    gt = np.array([[1.0, 2.0, np.nan], [4.0, 5.0, 6.0]])
    pred = np.array([[1.1, 2.0, 3.0], [4.0, 4.8, np.nan]])  # NaN pred counts as 0 m
    m = M.range_image_metrics(pred, gt, max_range=9.6)
    err = np.array([0.1, 0.0, 0.0, 0.2, 6.0])
    assert m["n"] == 5
    assert m["mean_cm"] == pytest.approx(err.mean() * 100)
    assert m["median_cm"] == pytest.approx(10.0)
    assert m["p90_cm"] == pytest.approx(np.percentile(err, 90) * 100)
    assert m["psnr_db"] == pytest.approx(10 * np.log10(9.6**2 / np.mean(err**2)))
    assert m["coverage"] == pytest.approx(4 / 5)


def test_range_image_metrics_edge_cases():
    gt = np.full((4, 4), np.nan)
    m = M.range_image_metrics(np.ones((4, 4)), gt)
    assert m["n"] == 0 and np.isnan(m["mean_cm"]) and np.isnan(m["psnr_db"])
    gt = np.random.default_rng(0).uniform(1, 9, (8, 8))
    m = M.range_image_metrics(gt, gt)
    assert m["mean_cm"] == 0 and m["psnr_db"] == np.inf
    with pytest.raises(ValueError):
        M.range_image_metrics(np.ones(3), np.ones(4))


def test_point_cloud_metrics_hand_computed():
    G = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    P = np.array([[0.0, 0.05, 0], [1.0, 0.2, 0], [3.0, 0, 0]])
    m = M.point_cloud_metrics(P, G, tau=0.10)
    d_pg = np.array([0.05, 0.2, 2.0])
    d_gp = np.array([0.05, 0.2])
    assert m["cd"] == pytest.approx(d_pg.mean() + d_gp.mean())
    assert m["mhd"] == pytest.approx(max(d_pg.mean(), d_gp.mean()))
    assert m["precision"] == pytest.approx(1 / 3)
    assert m["recall"] == pytest.approx(1 / 2)
    assert m["f_score"] == pytest.approx(2 * (1 / 3) * (1 / 2) / (1 / 3 + 1 / 2))
    avg = M.point_cloud_metrics(P, G, cd_mode="mean")
    assert avg["cd"] == pytest.approx(0.5 * m["cd"])
    sq = M.point_cloud_metrics(P, G, squared=True)
    assert sq["cd"] == pytest.approx((d_pg**2).mean() + (d_gp**2).mean())
    cut = M.point_cloud_metrics(P, G, max_dist=0.5)
    assert cut["cd"] == pytest.approx(np.minimum(d_pg, 0.5).mean() + d_gp.mean())


def test_point_cloud_metrics_brute_force_random():
    rng = np.random.default_rng(1)
    P, G = rng.normal(size=(300, 3)), rng.normal(size=(200, 3))
    D = np.linalg.norm(P[:, None] - G[None], axis=-1)
    m = M.point_cloud_metrics(P, G, tau=0.3)
    assert m["cd"] == pytest.approx(D.min(1).mean() + D.min(0).mean())
    assert m["precision"] == pytest.approx(np.mean(D.min(1) < 0.3))
    assert m["recall"] == pytest.approx(np.mean(D.min(0) < 0.3))


def test_point_cloud_metrics_empty_and_identical():
    G = np.random.default_rng(2).normal(size=(50, 3))
    same = M.point_cloud_metrics(G, G)
    assert same["cd"] == 0 and same["mhd"] == 0 and same["f_score"] == 1
    e = M.point_cloud_metrics(np.zeros((0, 3)), G)
    assert e["cd"] == np.inf and e["precision"] == 0 and e["recall"] == 0 and e["f_score"] == 0
    e2 = M.point_cloud_metrics(G, np.zeros((0, 3)))
    assert e2["cd"] == np.inf and e2["precision"] == 0 and e2["f_score"] == 0
    both = M.point_cloud_metrics(np.zeros((0, 3)), [])
    assert both["cd"] == 0 and both["f_score"] == 1
    # NaN rows are dropped, not matched
    Pn = np.vstack([G, [[np.nan] * 3]])
    assert M.point_cloud_metrics(Pn, G)["cd"] == 0


def test_prf_curve_monotone_and_consistent():
    rng = np.random.default_rng(3)
    G = rng.uniform(0, 5, (500, 3))
    P = G + rng.normal(scale=0.08, size=G.shape)
    c = M.prf_curve(P, G, taus=[0.02, 0.1, 0.3])
    assert np.all(np.diff(c["precision"]) >= 0) and np.all(np.diff(c["recall"]) >= 0)
    assert c["f_score"][1] == pytest.approx(M.point_cloud_metrics(P, G, tau=0.1)["f_score"])


def test_human_detection_hand_computed():
    gt = [np.array([[0.0, 0, 0]]), np.array([[5.0, 0, 0]]), np.full((1, 3), np.nan)]
    pred = [np.array([[0.1, 0, 0], [3.0, 0, 0]]), np.array([[5.6, 0, 0]]), np.zeros((0, 3))]
    m = M.human_detection_metrics(pred, gt)
    # frame 0: 1 TP (0.1 m) + 1 FP; frame 1: 0.6 m > 0.5 → FP + FN; frame 2: nothing
    assert m["tp"] == 1 and m["n_pred"] == 3 and m["n_gt"] == 2
    assert m["precision"] == pytest.approx(1 / 3) and m["recall"] == pytest.approx(1 / 2)
    assert m["loc_mean_cm"] == pytest.approx(10.0)
    perfect = M.human_detection_metrics(gt, gt)
    assert perfect["f_score"] == 1 and perfect["loc_mean_cm"] == 0
    nobody = M.human_detection_metrics([np.zeros((0, 3))], [np.full((1, 3), np.nan)])
    assert np.isnan(nobody["f_score"]) and np.isnan(nobody["recall"]) and np.isnan(nobody["precision"])
    ghost = M.human_detection_metrics([np.ones((1, 3))], [np.zeros((0, 3))])
    assert ghost["precision"] == 0 and np.isnan(ghost["f_score"])


def test_human_centroids_clusters():
    rng = np.random.default_rng(4)
    a = rng.normal([1, 1, 1], 0.05, (40, 3))
    b = rng.normal([4, 0, 1], 0.05, (30, 3))
    lone = np.array([[9.0, 9, 9]])
    c = M.human_centroids(np.vstack([a, b, lone]), radius=0.3, min_points=5)
    c = c[np.argsort(c[:, 0])]
    assert c.shape == (2, 3)
    np.testing.assert_allclose(c[0], a.mean(0)) and np.testing.assert_allclose(c[1], b.mean(0))


def test_bands_and_breakdown():
    assert [M.width_band(w) for w in (1.2, 1.5, 3.0, 3.1)] == ["narrow", "medium", "medium", "wide"]
    assert [M.attenuation_band(d) for d in (5, 10, 20, 25, None)] == ["low", "medium", "medium", "high", None]
    assert M.scene_attenuation_db({"stats": {"los_nlos_human_drop_db": 12.5}}) == 12.5
    rows = [
        {"bands": M.scene_bands({"corner_type": "T", "width_m": 2.0, "attenuation_db": 5}), "n_frames": 1, "cd": 1.0},
        {"bands": M.scene_bands({"corner_type": "T", "width_m": 1.0, "attenuation_db": 25}), "n_frames": 3, "cd": 3.0},
        {"bands": M.scene_bands({"corner_type": "L", "width_m": 4.0}), "n_frames": 2, "cd": 2.0},
    ]
    b = M.breakdown(rows, keys=["cd"])
    assert b["shape"]["T"]["cd"] == pytest.approx((1 * 1 + 3 * 3) / 4) and b["shape"]["T"]["n_scenes"] == 2
    assert set(b["width"]) == {"narrow", "medium", "wide"}
    assert set(b["attenuation"]) == {"low", "high"}


def test_estimate_attenuation_db():
    T, N, H, W = 1, 32, 2, 2
    hm = np.full((T, N, H, W), 1e-3)
    R = np.full((T, 2, H, W), np.nan)
    L = np.zeros((T, 2, H, W), np.uint8)
    R[0, 0], L[0, 0] = 0.5, 1   # LOS at bin 5
    R[0, 1, 0, 0], L[0, 1, 0, 0] = 1.0, 4  # NLOS human at bin 10
    hm[0, 5] = 1.0
    hm[0, 10] = 0.1
    assert M.estimate_attenuation_db(hm, R, L, dr=0.1) == pytest.approx(20.0)


def test_strongest_clusters_ranks_clusters_by_summed_weight():
    from holodata.metrics import strongest_clusters

    rng = np.random.default_rng(0)
    a = rng.normal([0, 0, 0], 0.05, (20, 3))     # 20 points of weight 1: sum 20
    b = rng.normal([3, 0, 0], 0.05, (10, 3))     # 10 points of weight 5: sum 50
    c = rng.normal([6, 0, 0], 0.05, (3, 3))      # too few points to be a cluster, however heavy
    P = np.vstack([a, b, c, [[np.nan, 0, 0]]])
    w = np.r_[np.ones(20), np.full(10, 5.0), np.full(3, 100.0), 1e9]
    got = strongest_clusters(P, w, k=2, min_sum=0.0)
    assert got.shape == (2, 3)
    assert np.allclose(got[0], b.mean(0)) and np.allclose(got[1], a.mean(0))
    assert np.allclose(strongest_clusters(P, w, k=2, min_sum=30.0), b.mean(0, keepdims=True))
    assert strongest_clusters(P, w, k=1, min_sum=51.0).shape == (0, 3)
    assert strongest_clusters(P[:3], w[:3], k=1, min_sum=0.0).shape == (0, 3)
