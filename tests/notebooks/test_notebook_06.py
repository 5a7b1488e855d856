"""Notebook 06 (the Ventoux Pleiades crops through match -> adjust -> ortho -> dsm ->
coregister): the statements of its text, checked on the numbers it prints
(``NOTEBOOK_RESULTS``), on the run of the test and on the committed run. It has no quick mode
(the crops are 500 px; its time is compilation): the bounds below hold on both runs, and the
numbers the text quotes are checked on the committed run, to the text's rounding."""

import numpy as np

NAME = "06_ventoux_real_images"


def check(r: dict) -> None:
    """The text's statements, with room for another machine's matching."""
    assert 45.0 < r["geoid_m"] < 55.0, r  # EGM96 at Mont Ventoux: about +50 m
    m = r["match"]
    # hundreds of ties; the RPCs' relative bias: a consistent offset of ~-4.75 px across the
    # epipolar curves (its spread a fraction of a pixel)
    assert m["ties"] > 500 and m["ties"] <= m["candidates"], m
    assert -5.5 < m["across_px"] < -4.0 and m["across_sigma_px"] < 0.6, m
    a = r["adjust"]
    assert a["converged"] and 0.3 < a["s0"] < 1.0, a
    for name in ("left_image", "right_image"):
        before, after = np.array(a["rms_before_px"][name]), np.array(a["rms_after_px"][name])
        # before: pixels, mostly in columns; after: matching noise, > 5x smaller
        assert before[0] > 1.5 and np.all(after < 0.3), a
        assert np.linalg.norm(before) > 5 * np.linalg.norm(after), a
    # the across-epipolar offset removed; the signed residual's peak moves to 0, same width
    assert abs(a["across_before_px"]) > 4.0 and abs(a["across_after_px"]) < 0.2, a
    (mb, sb), (ma, sa) = a["signed_px"]["before"], a["signed_px"]["after"]
    assert mb > 2.0 and abs(ma) < 0.05 and abs(sb - sa) < 0.05, a
    # the relative shift determined to a fraction of a pixel, the absolute one by the prior;
    # split between the images: each moves ~1.4 m on the ground, in opposite directions
    assert 4.5 < np.linalg.norm(a["relative_px"]) < 6.5, a
    assert max(a["relative_sigma_px"]) < 0.5 < 3.0 < a["absolute_sigma_px"], a
    left, right = np.array(a["moved_m"]["left_image"]), np.array(a["moved_m"]["right_image"])
    assert 0.8 < np.linalg.norm(left) < 2.5 and 0.8 < np.linalg.norm(right) < 2.5, a
    assert left @ right < 0, a
    o = r["ortho"]
    assert o["res_m"] == 0.5 and 0.85 < o["valid_fraction"] < 0.95, o
    d = r["dsm"]
    # a fifth of the grid seen by both images, most of it with a height; the adjusted
    # orientation at least halves the median height sigma
    assert 0.15 < d["overlap_fraction"] < 0.3 and d["filled_in_overlap"] > 0.7, d
    assert d["filled"] < d["overlap_fraction"] and d["interpolated_of_heights"] < 0.02, d
    assert d["median_sigma_m"] < 0.8 and d["median_sigma_m"] < d["median_sigma_delivered_m"] / 2
    # the empty ring: no height next to the overlap's edge (matching windows that meet no
    # data), a full overlap deeper in; a few metres wide, holding a large share of the holes
    fill = d["fill_by_edge_distance"]
    assert max(fill[:2]) < 0.05 and d["fill_beyond_15m"] > 0.9, d
    assert 1 <= d["ring_m"] <= 6 and all(f < 0.05 for f in fill[: d["ring_m"]]), d
    assert d["holes_in_ring"] > 0.3 and d["ring_share"] < 0.25, d
    # ... and no cluster of wrong heights at the DSM's edges: as rare there as inside
    edge, inside = d["outliers"]["edge"], d["outliers"]["inside"]
    assert edge["cells"] > 500 and edge["fraction"] < 0.01 and inside["fraction"] < 0.01, d
    c = r["cars"]
    # the delivered models' DSM on CARS' triangulation; the adjusted one several metres lower
    assert abs(c["delivered"]["median_m"]) < 0.5 and c["delivered"]["nmad_m"] < 0.6, c
    assert c["delivered"]["cells"] > 10_000, c
    lowered = c["adjusted"]["median_m"] - c["delivered"]["median_m"]
    assert -6.0 < lowered < -2.0 and abs(c["adjusted"]["nmad_m"] - c["delivered"]["nmad_m"]) < 0.1
    f = r["coregister_refused"]
    # a DSM a few SRTM posts across: the horizontal fit refused up front, the command exits 2
    # naming --vertical-only
    assert f["exit"] == 2 and f["names_option"] is True, f
    assert f["posts"][0] < 5 and f["posts"][1] < 2, f
    s = r["coregister_srtm"]
    # vertical only: no horizontal move, dz the median taken out, the same cells before and
    # after; NMAD SRTM's (metres), unchanged by a constant; the adjusted DSM on SRTM's datum
    # (the tie heights), the delivered models' DSM metres above it
    assert s["converged"] and s["shift_m"][:2] == [0.0, 0.0], s
    assert abs(s["shift_m"][2] + s["before"]["median_m"]) < 0.05, s
    assert abs(s["after"]["median_m"]) < 0.05 and s["before"]["cells"] == s["after"]["cells"], s
    assert s["before"]["nmad_m"] > 5.0 and abs(s["after"]["nmad_m"] - s["before"]["nmad_m"]) < 0.1
    assert abs(s["shift_m"][2]) < 1.5 and s["shift_m"][2] - s["delivered_dz_m"] > 2.0, s
    g = r["coregister_delivered"]
    # onto the delivered models' DSM: converged, a height change, almost no horizontal move,
    # the CARS comparison's lowering undone
    assert g["converged"] and np.hypot(*g["shift_m"][:2]) < 0.5, g
    assert (
        abs(g["shift_m"][2] + lowered) < 0.5
        and abs(g["before"]["median_m"] + g["shift_m"][2]) < 0.5
    )
    assert abs(g["after"]["median_m"]) < 0.05 and g["after"]["nmad_m"] < 0.3, g


def near(value, quoted, decimals):
    """``value`` (4 significant digits) is what the text quotes, rounded to ``decimals``."""
    return abs(value - quoted) <= 0.5 * 10.0**-decimals + 1e-3 * abs(quoted) + 1e-9


def test_notebook_06_runs(run_notebook):
    run = run_notebook("06_ventoux_real_images")
    check(run.results)


def test_notebook_06_committed_outputs(committed_results):
    r = committed_results(NAME)
    check(r)
    # the numbers quoted in the text (as it rounds them)
    m = r["match"]
    assert (m["ties"], m["candidates"]) == (689, 907), m
    assert near(m["across_px"], -4.75, 2) and near(m["across_sigma_px"], 0.33, 2), m
    assert [round(h) for h in m["heights_m"][::2]] == [514, 561], m
    a = r["adjust"]
    quoted = {"rms_before_px": {"left_image": (2.32, 0.62), "right_image": (2.33, 0.64)},
              "rms_after_px": {"left_image": (0.17, 0.05), "right_image": (0.18, 0.05)},
              "shift_px": {"left_image": (-1.97, -1.95), "right_image": (1.92, 2.03)}}  # fmt: skip
    for key, per_image in quoted.items():
        for name, values in per_image.items():
            assert all(near(v, q, 2) for v, q in zip(a[key][name], values, strict=True)), (key, a)
    assert near(a["across_after_px"], 0.03, 2) and near(a["s0"], 0.61, 2), a
    assert near(a["relative_px"][0], 3.89, 2) and near(a["relative_px"][1], 3.98, 2), a
    assert near(a["relative_sigma_px"][0], 0.05, 2) and near(a["relative_sigma_px"][1], 0.18, 2)
    assert near(np.linalg.norm(a["relative_px"]), 5.57, 2) and near(a["absolute_sigma_px"], 4.3, 1)
    assert all(near(np.linalg.norm(v), 1.4, 1) for v in a["moved_m"].values()), a
    (mb, sb), (ma, sa) = a["signed_px"]["before"], a["signed_px"]["after"]
    assert near(mb, 2.39, 2) and near(ma, 0.0, 2) and near(sb, 0.18, 2) and near(sa, 0.18, 2)
    o = r["ortho"]
    assert o["size_px"] == [533, 514] and near(o["valid_fraction"], 0.905, 3), o
    assert near(o["gsd_m"], 0.499, 3), o
    d = r["dsm"]
    assert near(d["overlap_fraction"], 0.220, 3) and near(d["filled"], 0.179, 3), d
    assert near(d["filled_in_overlap"], 0.811, 3) and near(d["interpolated_of_heights"], 0.002, 3)
    assert near(d["median_sigma_m"], 0.45, 2) and near(d["median_sigma_delivered_m"], 1.47, 2), d
    fill = d["fill_by_edge_distance"]
    assert [round(100 * f) for f in fill[:4]] == [0, 1, 2, 14] and near(fill[9], 0.92, 2), d
    assert d["ring_m"] == 3 and near(d["fill_beyond_15m"], 1.0, 3), d
    assert near(d["ring_share"], 0.096, 3) and near(d["holes_in_ring"], 0.51, 2), d
    edge, inside = d["outliers"]["edge"], d["outliers"]["inside"]
    assert edge["cells"] == 1708 and near(edge["fraction"], 0.0023, 4), d
    assert near(inside["fraction"], 0.0012, 4), d
    c = r["cars"]
    assert c["delivered"]["cells"] == 13_069, c
    assert near(c["delivered"]["median_m"], 0.06, 2) and near(c["delivered"]["nmad_m"], 0.35, 2)
    assert near(c["adjusted"]["median_m"], -3.94, 2), c
    f = r["coregister_refused"]
    assert [round(p, 1) for p in f["posts"]] == [3.1, 0.9], f
    assert [round(v) for v in f["post_spacing_m"]] == [66, 93], f
    s = r["coregister_srtm"]
    assert near(s["shift_m"][2], -0.12, 2) and near(s["before"]["median_m"], 0.12, 2), s
    assert near(s["after"]["median_m"], -0.01, 2) and s["before"]["cells"] == 14_548, s
    assert near(s["before"]["nmad_m"], 10.51, 2) and near(s["after"]["nmad_m"], 10.51, 2), s
    assert near(s["delivered_dz_m"], -3.99, 2), s
    g = r["coregister_delivered"]
    assert g["iterations"] == 9, g
    assert all(near(v, q, 2) for v, q in zip(g["shift_m"], (0.04, -0.07, 4.04), strict=True)), g
    assert near(g["before"]["median_m"], -4.03, 2) and near(g["before"]["nmad_m"], 0.09, 2), g
    assert near(g["after"]["median_m"], 0.0, 2) and near(g["after"]["nmad_m"], 0.09, 2), g
