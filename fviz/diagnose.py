"""Per-pair evidence for triage, computed by ``eval`` while the matches are at hand and stored in
results.jsonl (``diagnostics``): fviz.run imports this module, fviz.triage reads what it wrote.
The two-view checks (:func:`two_view_evidence`: COLMAP's label, the Bougnoux focals; ~30-40 ms and
pycolmap's import per pair) are left to triage, which computes them for the pairs it lists.

Thresholds live here, beside the computations that use them; fviz.triage documents the tags.

:func:`gt_suspect` is a property of the pair, judged once from the estimators that fit the matches (not the
baselines, not the networks, which read only the images), whichever estimator triage ranks by: inspect
(stdout, JSON ``notes``, the recording) and triage (the tag) call it on the same evidence.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fviz.evaluate import EVAL_THRESHOLD_PX, GT_NAME
from fviz.evidence import GT_OWN_SHARE, GT_OWN_TIGHT, MIN_EVIDENCE, STATIC_FRACTION, STATIC_PX, heldout_sed, input_evidence, input_mistake  # noqa: F401 (re-exported)
from fviz.geometry.homography import HOMOGRAPHY_PX, MIN_FIT, homography_fraction  # noqa: F401 (re-exported)
from fviz.stats import number

ROTATION_PX = 2.0
DEGENERATE_H_FRACTION = 0.9  # one homography explains this share of all matches: a plane or a pure rotation
FOCAL_PROBE_PX = 0.5  # focal_observable: noise added to exact matches, draws, matches used,
FOCAL_PROBE_RUNS = 3
FOCAL_PROBE_POINTS = 300
FOCAL_STABLE = 0.25  # and the largest relative focal error that still counts as determined
# gt-suspect (see gt_suspect) and the conditioning of a pair (shared with the tags of fviz.triage)
GT_SUSPECT_INLIER_RATIO = 0.5  # a consensus: at least this share of the matches are an estimator's inliers
GT_SUSPECT_FIT_PX = 0.5  # a tight fit: median SED below this
GT_SUSPECT_DIRECTION_DEG = 6.0
GT_SUSPECT_ROTATION_DEG = 1.0
GT_SUSPECT_AGREE_SHARE = 0.5  # the tight fits' directions within this share of their offset from F_gt's of each other
# the ground truth must explain the matches worse than the estimates do: its median SED on an estimate's inliers
# above GT_SUSPECT_RATIO times the estimate's own, and above it by a margin that grows with the ground truth's stated
# accuracy (Pair.gt_accuracy_px): GT_SUSPECT_MARGIN_PX or half the accuracy on the residuals alone, and
# GT_SUSPECT_DIRECTION_MARGIN_PX or a tenth of it where the direction test (forward motion) adds its evidence
GT_SUSPECT_RATIO = 1.5
GT_SUSPECT_MARGIN_PX = 1.0
GT_SUSPECT_ACCURACY_SHARE = 0.5
GT_SUSPECT_DIRECTION_MARGIN_PX = 0.25
GT_SUSPECT_DIRECTION_ACCURACY_SHARE = 0.1
GT_SUSPECT_EPIPOLE_NEAR = 1.0  # the direction test only where F_gt's epipoles lie within this many image diagonals
# of the image centres (forward motion): farther (sideways motion, rectified stereo: at infinity) a direction
# several degrees off moves the lines by less than the matches' noise, and says nothing
# a ground truth biased over a run (gt_bias): the tight fits' epipole on one side of F_gt's on most pairs
GT_BIAS_MIN_PAIRS = 8
GT_BIAS_P = 0.05  # two-sided sign test
GT_BIAS_MIN_DEG = 0.2  # and a median offset at least this large (KITTI: 2.5 px at f = 721)
PLANAR_FRACTION = 0.8
SMALL_BASELINE_M = 0.1
ROTATION_FRACTION = 0.8


def rotation_fraction(pair, x_a: np.ndarray, x_b: np.ndarray) -> float:
    """Fraction of matches the infinite homography K_b R K_a^-1 maps within ROTATION_PX."""
    if len(x_a) == 0:
        return float("nan")
    H = pair.K_b @ pair.R @ np.linalg.inv(pair.K_a)
    p = np.c_[x_a, np.ones(len(x_a))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(p[:, :2] / p[:, 2:] - x_b, axis=1)
    return float(np.mean(np.nan_to_num(err, nan=np.inf) < ROTATION_PX))


def focals(pair, F: np.ndarray) -> list[float]:
    """[f_a, f_b] px of F by Bougnoux's formula (PoseLib) at K's principal points; NaN where imaginary,
    and where PoseLib is not installed."""
    if not pair.has_K:
        return [float("nan")] * 2
    try:
        from fviz.estimators.external import bougnoux_focals

        return list(bougnoux_focals(F, pair.K_a[:2, 2], pair.K_b[:2, 2]))
    except ImportError:
        return [float("nan")] * 2


def focal_observable(pair, x_a: np.ndarray, x_b: np.ndarray) -> bool:
    """Whether these matches determine the focal lengths through F: moved onto F_gt's epipolar lines (x_b to
    the nearest point of F_gt x_a), with FOCAL_PROBE_PX of Gaussian noise added (FOCAL_PROBE_RUNS seeded draws),
    an 8-point F fitted to them gives Bougnoux focals within FOCAL_STABLE of K's every time. False on rectified
    stereo and on forward motion, where the formula is (nearly) singular and any estimate's focals say nothing."""
    import cv2

    from fviz.geometry import homogeneous, lines_in_b

    if len(x_a) < MIN_FIT or not (pair.has_gt and pair.has_K):
        return False
    x_a, x_b = x_a[:FOCAL_PROBE_POINTS], x_b[:FOCAL_PROBE_POINTS]  # the best matches: enough for an 8-point F
    f_true = np.array([pair.K_a[0, 0], pair.K_b[0, 0]])
    l_b = lines_in_b(pair.F_gt, x_a)  # unit normals: x_b moved to the foot of its perpendicular on F_gt x_a
    on_line = x_b - (np.einsum("ni,ni->n", l_b, homogeneous(x_b)))[:, None] * l_b[:, :2]
    rng = np.random.default_rng(0)
    for _ in range(FOCAL_PROBE_RUNS):
        na, nb = (c + rng.normal(0, FOCAL_PROBE_PX, c.shape) for c in (np.asarray(x_a, np.float64), on_line))
        F, _ = cv2.findFundamentalMat(na, nb, cv2.FM_8POINT)
        f = np.array(focals(pair, F[:3])) if F is not None else np.full(2, np.nan)
        if not np.all(np.abs(f / f_true - 1) < FOCAL_STABLE):  # NaN (imaginary) fails too
            return False
    return True


def two_view_label(pair, m) -> str:
    """COLMAP's two-view configuration of the matches (``n/a`` where pycolmap is not installed, or the cameras unknown)."""
    if not pair.has_K:
        return "n/a"
    try:
        from fviz.estimators.external import two_view_configuration
    except ImportError:
        return "n/a"
    return two_view_configuration(pair, m.x_a, m.x_b)


def _estimator_evidence(pair, r, m, gt_sed: np.ndarray, eval_threshold: float) -> dict[str, float]:
    inl = np.zeros(len(m), bool) if r.inliers is None else r.inliers
    n = int(inl.sum())
    known = n and gt_sed is not None
    from fviz.geometry import symmetric_epipolar_distance

    own = symmetric_epipolar_distance(r.F, m.x_a[inl], m.x_b[inl]) if n else np.zeros(0)
    heldout = heldout_sed(m.x_a[inl], m.x_b[inl])
    return {
        "n_inliers": n,
        "sed_median_inliers": float(np.median(own)) if n else float("nan"),
        "sed_median_heldout": float(np.nanmedian(heldout)) if np.isfinite(heldout).any() else float("nan"),
        "homography_fraction": homography_fraction(m.x_a[inl], m.x_b[inl]),
        "gt_agree": float(np.mean(gt_sed[inl] < eval_threshold)) if known else float("nan"),
        "gt_sed_median_inliers": float(np.median(gt_sed[inl])) if known else float("nan"),
        "epipole_ray": epipole_ray(pair.K_a, r.F) if pair.has_K else None,
    }


def epipole_ray(K: np.ndarray, F: np.ndarray) -> list[float]:
    """The unit viewing ray K^-1 e through F's epipole in image a, turned to look forward (z >= 0): a direction of
    motion, comparable between estimates of one pair."""
    from fviz.geometry import epipoles

    r = np.linalg.solve(K, epipoles(F)[0])
    r = r / np.linalg.norm(r)
    return [float(v) for v in (r if r[2] >= 0 else -r)]


def _rays_apart_deg(rays: list) -> float:
    """The largest angle (deg) between any two of these rays, sign-free; NaN when one is missing."""
    if any(r is None for r in rays):
        return float("nan")
    u = np.array(rays, float)
    c = np.clip(np.abs(u @ u.T), 0.0, 1.0)
    return float(np.degrees(np.arccos(c.min())))


def _fitted(result) -> list:
    """The estimates of a result that have an F (the ground truth and failures left out)."""
    return [r for r in result.estimators if r.name != GT_NAME and not r.error]


def diagnose(pair, result, two_view: bool = True) -> dict[str, Any]:
    """Evidence for the tags of one evaluated pair (JSON-ready; NaN where undefined), and the
    straight-ahead baseline's median SED on the evaluation matches (``ahead_sed_median``), so that
    triage can compare every run with it whether or not ``-e ahead`` was given; with ``two_view`` also
    :func:`two_view_evidence` (eval leaves it out: triage adds it for the pairs it lists)."""
    from fviz.estimators.baselines import ahead
    from fviz.geometry import symmetric_epipolar_distance

    m = result.matches
    nan = float("nan")
    gt_sed = symmetric_epipolar_distance(pair.F_gt, m.x_a, m.x_b) if pair.has_gt else None  # the pair's GT, if any
    angle = np.degrees(np.arccos(np.clip((np.trace(pair.R) - 1) / 2, -1.0, 1.0))) if pair.R is not None else nan
    flow = np.linalg.norm(m.x_b - m.x_a, axis=1)
    xa, xb = m.x_a[result.eval_mask], m.x_b[result.eval_mask]
    ahead_sed = symmetric_epipolar_distance(ahead(pair, xa, xb), xa, xb) if pair.has_K else np.zeros(0)
    diag = {
        "n_matches": len(m),
        "gt_accuracy_px": pair.gt_accuracy_px,
        "gt_epipole_distance": gt_epipole_distance(pair) if pair.has_gt else nan,
        "baseline_m": float(np.linalg.norm(pair.t)) if pair.t is not None else nan,
        "rotation_deg": float(angle),
        "median_flow_px": float(np.median(flow)) if len(m) else float("nan"),
        "static_fraction": float(np.mean(flow < STATIC_PX)) if len(m) else float("nan"),
        "rotation_fraction": rotation_fraction(pair, m.x_a, m.x_b) if pair.has_pose else nan,
        "ahead_sed_median": float(np.median(ahead_sed)) if len(ahead_sed) else float("nan"),
        "homography_fraction": homography_fraction(m.x_a, m.x_b),
        "inputs": input_evidence(pair, m.x_a, m.x_b, result.eval_threshold_px),
        "estimators": {r.name: _estimator_evidence(pair, r, m, gt_sed, result.eval_threshold_px) for r in _fitted(result)},
    }
    return with_two_view(diag, two_view_evidence(pair, result)) if two_view else diag


def diagnosed(pair, result) -> dict[str, Any]:
    """:func:`diagnose` (``two_view=False``) of an evaluated pair, computed once per result (the ground-truth check
    and the verdict both read it)."""
    key = (id(pair), len(result.matches), tuple(id(r) for r in result.estimators))
    cached = getattr(result, "_diagnosed", None)
    if cached is None or cached[0] != key:
        cached = (key, diagnose(pair, result, two_view=False))
        result._diagnosed = cached
    return cached[1]


def gt_epipole_distance(pair) -> float:
    """How far F_gt's epipoles lie from the image centres, in image diagonals (the larger of the two; inf for an
    epipole at infinity: rectified stereo)."""
    from fviz.geometry import epipoles

    far = 0.0
    for e, (w, h) in zip(epipoles(pair.F_gt), (pair.size_a, pair.size_b)):
        diag = float(np.hypot(w, h))
        if abs(e[2]) * 1e6 <= np.linalg.norm(e[:2]):
            return float("inf")
        far = max(far, float(np.hypot(e[0] / e[2] - w / 2, e[1] / e[2] - h / 2)) / diag)
    return far


def two_view_evidence(pair, result) -> dict[str, Any]:
    """COLMAP's two-view label of the matches (``two_view``), whether the evaluation matches determine the focal
    lengths through F (``focal_observable``) and, per estimator, its Bougnoux focals (``estimators``: {name:
    {"focals"}}): the evidence of triage's ``colmap-*`` and ``focal-implausible`` tags."""
    m = result.matches
    return {
        "two_view": two_view_label(pair, m),
        "focal_observable": focal_observable(pair, m.x_a[result.eval_mask], m.x_b[result.eval_mask]),
        "estimators": {r.name: {"focals": focals(pair, r.F)} for r in _fitted(result)},
    }


def has_two_view(diag: dict[str, Any] | None) -> bool:
    """Whether a record's diagnostics already hold :func:`two_view_evidence` (earlier versions of eval stored it)."""
    return bool(diag) and "two_view" in diag


def with_two_view(diag: dict[str, Any], evidence: dict[str, Any]) -> dict[str, Any]:
    """Diagnostics (:func:`diagnose`) with the two-view evidence merged in (a new dict)."""
    ests = {name: {**ev, **evidence["estimators"].get(name, {})} for name, ev in diag.get("estimators", {}).items()}
    return {**diag, **{k: v for k, v in evidence.items() if k != "estimators"}, "estimators": ests}


def fits_matches(name: str) -> bool:
    """Estimators whose F is fitted to the matches: not the baselines, not the networks (images only)."""
    from fviz.estimators.registry import is_baseline

    return name != GT_NAME and not is_baseline(name) and name != "deep" and not name.startswith("deep-")


def ill_conditioned(diag: dict[str, Any], ev: dict[str, Any]) -> str:
    """Why the epipolar geometry of the pair is poorly determined ("" when it is not): a small baseline,
    the infinite homography explaining most matches, or one plane holding most of the inliers ``ev``."""
    rot, hom = number(diag.get("rotation_fraction")), number(ev.get("homography_fraction"))
    if number(diag.get("baseline_m")) < SMALL_BASELINE_M:
        return f"small baseline (|t| = {number(diag.get('baseline_m')):.3f} m)"
    if rot >= ROTATION_FRACTION:
        return f"a pure rotation explains {rot:.0%} of the matches"
    if hom >= PLANAR_FRACTION:
        return f"one homography explains {hom:.0%} of the inliers"
    return ""


def _margins(diag: dict[str, Any]) -> tuple[float, float]:
    """(residual margin, direction margin) px for this pair's ground truth (its stated accuracy; 0 when unknown)."""
    acc = number(diag.get("gt_accuracy_px"))
    acc = 0.0 if not np.isfinite(acc) else acc
    return (max(GT_SUSPECT_MARGIN_PX, GT_SUSPECT_ACCURACY_SHARE * acc),
            max(GT_SUSPECT_DIRECTION_MARGIN_PX, GT_SUSPECT_DIRECTION_ACCURACY_SHARE * acc))


def gt_own_consensus(diag: dict[str, Any], estimators: list[dict[str, Any]]) -> str:
    """"" or why the ground truth has a tight consensus of its own among the matches: GT_OWN_SHARE of them (and
    MIN_EVIDENCE) within the evaluation threshold of its lines, their median SED below GT_OWN_TIGHT of it and no more
    than GT_SUSPECT_RATIO times the largest robust consensus's held-out one (the ground truth fits its set as well as
    the best estimate fits its own: two consistent sets, a matcher fooled by repeated texture). A translation a few
    degrees off on forward motion leaves many matches near F_gt's lines too, but loosely: 3-5 times the estimates'
    held-out residual. -> "312 of the 690 matches lie a median 0.3 px from F_gt's lines"."""
    n, near = number(diag.get("n_matches")), number(((diag.get("inputs") or {}).get("n_gt")))
    gt = next((e for e in estimators if e["name"] == GT_NAME), None)
    band = number((gt or {}).get("metrics", {}).get("sed_median"))  # over the evaluation matches: those near F_gt
    evidence = diag.get("estimators") or {}
    fits = [(number(e["metrics"].get("n_inliers")), number(evidence.get(e["name"], {}).get("sed_median_heldout")))
            for e in estimators if is_robust(e["name"]) and not e.get("error") and e["name"] in evidence]
    own = max(fits)[1] if fits else float("nan")
    if (near >= max(MIN_EVIDENCE, GT_OWN_SHARE * n) and band <= GT_OWN_TIGHT * EVAL_THRESHOLD_PX
            and band <= GT_SUSPECT_RATIO * own):
        return f"{near:.0f} of the {n:.0f} matches lie a median {band:.2g} px from F_gt's lines"
    return ""


def gt_suspect(diag: dict[str, Any] | None, estimators: list[dict[str, Any]]) -> dict[str, str] | None:
    """Whether the pair's ground truth looks wrong: {"why": ..., "short": the same in a few words (a pair's verdict,
    fviz.verdicts), "reference": the estimator to trust instead} or None. ``diag``: :func:`diagnose`'s evidence;
    ``estimators``: the pair's rows ({name, error, metrics}, as in results.jsonl and ``inspect --json``).

    Cheaper explanations first: never when the user's inputs explain the misfit (:func:`input_mistake`: swapped or
    rescaled matches, a K for another image), nor when the ground truth has a tight consensus of its own among the
    matches (:func:`gt_own_consensus`: two consistent sets, a matcher fooled by repeated texture). Evidence only from
    fits with redundancy: a robust estimator (:func:`is_robust`: not 7- or 8-point, whose least-squares F is pulled by
    every outlier) that finds a consensus (inlier ratio >= GT_SUSPECT_INLIER_RATIO) of at least MIN_EVIDENCE inliers (F's 7
    degrees of freedom and MIN_SPARE spare), measured out of sample (``sed_median_heldout``: :func:`heldout_sed`),
    never by its own fit's residuals (zero through 8 points whatever the points). The ground truth is suspect only
    when it explains those inliers worse than the held-out refits do: F_gt's median SED above GT_SUSPECT_RATIO times
    theirs and above it by a margin that grows with the ground truth's stated accuracy (``gt_accuracy_px``):

    - on the residuals alone: the largest consensus's inliers sit off F_gt by more than the residual margin
      (GT_SUSPECT_MARGIN_PX, or GT_SUSPECT_ACCURACY_SHARE of the accuracy): it holds on any pair, planar and
      small-baseline ones included;
    - or, on a well-conditioned pair (:func:`ill_conditioned` says nothing) whose F_gt puts the epipoles near the
      images (within GT_SUSPECT_EPIPOLE_NEAR diagonals: forward motion, where a pose 13 deg off still leaves most
      matches within 1-2 px of its lines), every tight fit (held-out median SED < GT_SUSPECT_FIT_PX), and there are
      at least two (a lone fit's direction may be its own error: redundancy) that agree with each other (their
      epipoles' directions closer than GT_SUSPECT_AGREE_SHARE of their offset from F_gt's), puts the epipole
      more than GT_SUSPECT_DIRECTION_DEG or the rotation more than GT_SUSPECT_ROTATION_DEG from the ground truth's,
      and fits its inliers better than F_gt does by the (smaller) direction margin. An epipole far from the image or
      at infinity (sideways motion, rectified stereo) is poorly determined: an estimate's being 6-20 deg off says
      nothing there, and neither does it where the ground truth fits the matches as well as the estimates."""
    if not diag or input_mistake(diag) or gt_own_consensus(diag, estimators):
        return None
    evidence = diag.get("estimators", {})
    rows = [e for e in estimators if not e.get("error") and is_robust(e["name"]) and e["name"] in evidence]
    m = {e["name"]: {k: number(e["metrics"].get(k)) for k in ("inlier_ratio", "n_inliers", "sed_median",
                                                                "epipole_err_deg", "rot_err_deg")} for e in rows}

    def residuals(n: str) -> tuple[float, float]:
        """(F_gt's median SED on the estimate's inliers, their held-out median SED); NaN for runs made before the
        held-out residuals were kept: not judged."""
        ev = evidence[n]
        return number(ev.get("gt_sed_median_inliers")), number(ev.get("sed_median_heldout"))

    consensus = [n for n in m if m[n]["inlier_ratio"] >= GT_SUSPECT_INLIER_RATIO and m[n]["n_inliers"] >= MIN_EVIDENCE
                 and np.isfinite(residuals(n)[1])]
    if not consensus:
        return None

    def worse(n: str, margin: float) -> bool:
        gt, own = residuals(n)
        return gt > GT_SUSPECT_RATIO * own and gt - own > margin  # NaN: False

    margin, direction_margin = _margins(diag)
    acc = number(diag.get("gt_accuracy_px"))
    stated = f"ground truth good to ~{acc:.2g} px" if np.isfinite(acc) else "ground truth of unstated accuracy"
    ref = max(consensus, key=lambda n: (m[n]["n_inliers"], -residuals(n)[1]))
    if worse(ref, margin):
        gt, own = residuals(ref)
        agree = number(evidence[ref].get("gt_agree"))
        k = int(m[ref]["n_inliers"])
        short = (f"{ref}'s {k} inliers ({m[ref]['inlier_ratio']:.0%}) sit {gt:.3g} px off F_gt's lines, {own:.2g} px "
                 "off F's refitted without them (out of sample)")
        return {"reference": ref, "short": short, "why": f"{ref}'s {k} inliers ({m[ref]['inlier_ratio']:.0%} of the "
                f"matches, the largest consensus) sit off F_gt: median {gt:.2f} px from its lines against {own:.2f} px "
                f"out of sample (each from an 8-point F fitted to the other inliers), {agree:.0%} within "
                f"{EVAL_THRESHOLD_PX:g} px (margin {margin:.2g} px: {stated})"}
    tight = [n for n in consensus if residuals(n)[1] < GT_SUSPECT_FIT_PX]
    far = number(diag.get("gt_epipole_distance"))
    if len(tight) < 2 or ill_conditioned(diag, evidence[ref]) or far > GT_SUSPECT_EPIPOLE_NEAR:  # NaN (older runs): judged
        return None
    # the tight fits agree with each other: their directions lie closer together than half their offset from the
    # ground truth's (an estimator's own scatter on forward motion reaches several degrees: one fit 6 deg to the left
    # and another 10 deg to the right accuse nothing)
    apart = _rays_apart_deg([evidence[n].get("epipole_ray") for n in tight])
    agree = apart < GT_SUSPECT_AGREE_SHARE * min(m[n]["epipole_err_deg"] for n in tight)  # NaN (older runs): False
    if agree and all((m[n]["epipole_err_deg"] > GT_SUSPECT_DIRECTION_DEG or m[n]["rot_err_deg"] > GT_SUSPECT_ROTATION_DEG)
                     and worse(n, direction_margin) for n in tight):
        best = max(tight, key=lambda n: m[n]["n_inliers"])
        return {"reference": best, "short": "every tight fit's epipole or rotation is off F_gt's (" + ", ".join(
                    f"{n}: epipole {m[n]['epipole_err_deg']:.1f} deg, rotation {m[n]['rot_err_deg']:.2f} deg" for n in tight)
                + f") and fits its inliers better out of sample (margin {direction_margin:.2g} px)",
                "why": "every tight fit disagrees with the ground truth and fits the matches "
                "better: " + "; ".join(f"{n} epipole {m[n]['epipole_err_deg']:.1f} deg, rotation "
                                       f"{m[n]['rot_err_deg']:.2f} deg off, its {int(m[n]['n_inliers'])} inliers "
                                       f"{residuals(n)[0]:.2f} px from F_gt's lines against {residuals(n)[1]:.2f} px "
                                       "out of sample" for n in tight)
                + f" (margin {direction_margin:.2g} px: {stated})"}
    return None


GT_SUSPECT_NOTE = "gt-suspect: "  # how the verdict starts in a pair's notes (inspect: stderr, JSON, summary)


def gt_suspect_note(pair, result) -> str | None:
    """The verdict of :func:`gt_suspect` on one evaluated pair as a note ("gt-suspect: why; reference: ..."),
    None when the ground truth looks right (or the pair has too few matches to judge)."""
    if not pair.has_gt or result.matches is None or len(result.matches) == 0 or result.eval_mask is None:
        return None
    suspect = gt_suspect(diagnosed(pair, result), result.to_dict()["estimators"])
    if suspect is None:
        return None
    return (f"{GT_SUSPECT_NOTE}{suspect['why']}; the overview draws {suspect['reference']}'s lines as "
            f"the reference (reference: {suspect['reference']})")


def _direction_deg(K: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(yaw, pitch) in degrees of the viewing ray K^-1 e through an epipole, the ray turned to look forward."""
    r = np.linalg.solve(K, e)
    r = r if r[2] >= 0 else -r
    return np.degrees(np.arctan2(r[:2], r[2]))


NON_ROBUST = ("7point", "8point")  # least-squares fits through every match: no consensus, no evidence of a bias


def is_robust(name: str) -> bool:
    """A robust estimator that fits the matches (a consensus of inliers): not 7- or 8-point, baselines or networks."""
    return fits_matches(name) and name.partition("@")[0] not in NON_ROBUST


def pair_epipole_offset(rec: dict[str, Any]) -> tuple[dict[str, np.ndarray], float] | None:
    """The evidence :func:`gt_bias` reads from one results.jsonl record: ({tight fit: the offset (yaw, pitch;
    deg) of its epipole in image a from F_gt's}, camera a's focal length), on a pair with forward motion (F_gt's
    epipole within GT_SUSPECT_EPIPOLE_NEAR diagonals of the image); None elsewhere. A tight fit: a robust estimator
    (:func:`is_robust`) with at least MIN_EVIDENCE inliers whose held-out median SED is below GT_SUSPECT_FIT_PX."""
    from fviz.geometry import epipoles

    res, diag = rec.get("result"), rec.get("diagnostics") or {}
    if rec.get("error") or not res or res.get("F_gt") is None or res["pair"].get("K_a") is None:
        return None
    if not number(diag.get("gt_epipole_distance")) <= GT_SUSPECT_EPIPOLE_NEAR or input_mistake(diag):
        return None
    K, F_gt = np.array(res["pair"]["K_a"]), np.array(res["F_gt"])
    g = _direction_deg(K, epipoles(F_gt)[0])
    ev = diag.get("estimators") or {}

    def tight(name: str) -> bool:
        e = ev.get(name, {})
        return number(e.get("n_inliers")) >= MIN_EVIDENCE and number(e.get("sed_median_heldout")) < GT_SUSPECT_FIT_PX

    fits = {e["name"]: _direction_deg(K, epipoles(np.array(e["F"]))[0]) - g for e in res["estimators"]
            if is_robust(e["name"]) and e.get("F") is not None and tight(e["name"])}
    return (fits, float(K[0, 0])) if fits else None


def gt_bias(evidence) -> dict[str, Any] | None:
    """A ground truth biased over a run, not only noisy (raw KITTI's oxts: its translation direction sits ~1 deg
    to one side of the images' on most pairs): per robust estimator, over the pairs' :func:`pair_epipole_offset`
    (``evidence``: their non-None values), per axis, a signed-rank test. A bias: the most significant of them over
    at least GT_BIAS_MIN_PAIRS pairs, p < GT_BIAS_P and |median| >= GT_BIAS_MIN_DEG, confirmed by a second robust
    estimator whose median offset on that axis lies on the same side by GT_BIAS_MIN_DEG too (one estimator alone, however significant,
    may be measuring its own bias: none is claimed). A noisy estimator (RANSAC's forward epipole) shows no
    significant side, but its median still agrees.
    -> {"estimator", "confirmed_by", "axis", "median_deg", "median_px", "pairs", "same_side", "p", "text"} or None."""
    evidence = list(evidence)
    per: dict[str, list[np.ndarray]] = {}
    for fits, _ in evidence:
        for name, offset in fits.items():
            per.setdefault(name, []).append(offset)
    from fviz.stats import wilcoxon_signed_rank

    tests = [(wilcoxon_signed_rank(np.array(o)[:, axis]).p, name, axis) for name, o in per.items()
             if len(o) >= GT_BIAS_MIN_PAIRS for axis in (0, 1)]
    tests = [t for t in tests if np.isfinite(t[0])]  # NaN: no non-zero offset
    if not tests:
        return None
    p, name, axis = min(tests)
    d = np.array(per[name])[:, axis]
    med = float(np.median(d))
    if p >= GT_BIAS_P or abs(med) < GT_BIAS_MIN_DEG:
        return None
    confirm = [o for o, offs in per.items() if o != name and len(offs) >= GT_BIAS_MIN_PAIRS
               and np.sign(np.median(np.array(offs)[:, axis])) == np.sign(med)
               and abs(np.median(np.array(offs)[:, axis])) >= GT_BIAS_MIN_DEG]
    if not confirm:
        return None
    px = float(np.tan(np.radians(abs(med))) * np.median([f for _, f in evidence]))
    same = int(max((d > 0).sum(), (d < 0).sum()))
    side = ("left of", "right of", "above", "below")[2 * axis + (med > 0)]
    return {"estimator": name, "confirmed_by": confirm, "axis": "xy"[axis], "median_deg": med, "median_px": px,
            "pairs": len(d), "same_side": same, "p": p,
            "text": (f"ground truth biased: {name}'s epipole sits {abs(med):.2f} deg ({px:.1f} px) {side} the "
                     f"ground truth's, on {same} of {len(d)} pairs (signed-rank p = {p:.2g}; {', '.join(confirm)} on the "
                     f"same side): translation and pose errors below ~{abs(med):.1f} deg measure the ground truth, not "
                     "the estimators")}
