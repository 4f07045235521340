"""Face transformer benchmark (Arai et al.): Fisher against SVM impression transfer vectors on ICT-FaceKit faces.

Data: ``$SWEEPCAST_DATA/face3d/ict/ict_face_area.npz`` (ICT-FaceKit, 9409 vertices in cm, 100
identity modes, 57 ARKit-named expression blendshapes, quads). A person is the neutral face plus
the identity modes with N(0, 1) weights; each person has an expression style (per-blendshape
gains exp(0.2 N(0,1)), a left/right asymmetry N(0, 0.1) and a size factor from the face's height);
the paper's six expressions (Table 1) are blendshape recipes (:data:`RECIPES`) scaled by an
intensity; every face gets small random brow/blink/squint activations and 0.1 mm scanner noise.

People are split three ways: the model is trained on split A (40 people x 7 faces = 280 meshes,
the paper's design, intensities U(0.7, 1.0)); an independent judge is trained on split J (other
people, same recipe): its own PCA of the displacements and a multinomial logistic regression over
neutral + 6 expressions; the test people T are in neither. For every test person and expression,
the "non-emphasised" input is the expression at intensity 0.4 and the reference is the same
person's stronger real expression (intensity 1.0, same nuisance). Each method transforms the input
for a sweep of Q (the person's own neutral face as ``X_neutral``, as in the paper), and we report:

(i) perceptibility: the judge's decision value for the target expression, as log-odds
    ``z_t - logsumexp(z_others)`` (> 0: the judge is more sure of it than of all others), and its
    recognition rate;
(ii) the RMS vertex distance (mm) to the same person's stronger real expression;
(iii) plausibility: the Mahalanobis distance of the displacement in the judge's PCA space, the RMS
    part of the displacement outside that space (mm; zero for any mix of real expressions), and
    vertex-displacement statistics (mean, 95th percentile, max; mm).

Figs. 5-6 of the paper are redone with the judge instead of human raters: persons A-D are picked as
in the paper (k-means, 4 clusters of the test people's neutral faces in PCA space; in each the one
farthest from the origin), scored for closed and open smiles without emphasis, Fisher and SVM at Q=1.
Speed: training on the 280 meshes (median of repeats), and transforms of one 9409-vertex face
(median of many), with the two unavoidable matrix products timed in the same run as a baseline.

Run: ``python -m benchmarks.faces [--quick]`` from the repository root.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from sklearn.cluster import KMeans
from sklearn.linear_model import LogisticRegression
from sklearn.svm import SVC

from benchmarks import _plots as plots
from benchmarks._report import RESULTS_DIR, md_table, prog, publish
from benchmarks._timing import timed
from workers.common.datasets import dataset
from workers.faces.blas import single_threaded
from workers.faces.dataset import NEUTRAL, FaceDataset, load_dataset_zip, write_dataset_zip
from workers.faces.mesh import Mesh, read_mesh, replace_vertices, write_mesh
from workers.faces.pca import fit_pca
from workers.faces.preview import frame, preview_png, render
from workers.faces.synthetic import EXPRESSIONS
from workers.faces.train import TrainSettings, train_face_model
from workers.faces.transform import transform_mesh, transform_vertices

METHODS = ("fisher", "svm")
COLOURS = {"fisher": "tab:red", "svm": "tab:blue", "none": "tab:gray"}  # matplotlib colours
LR = ("_L", "_R")
# Blendshape weights of the paper's six expressions (names ending in "*" mean both _L and _R).
RECIPES: dict[str, dict[str, float]] = {
    "utter_a": {"jawOpen": 0.6, "mouthLowerDown*": 0.25, "mouthUpperUp*": 0.1},
    "utter_i": {"jawOpen": 0.15, "mouthStretch*": 0.5, "mouthSmile*": 0.15, "mouthUpperUp*": 0.15,
                "mouthLowerDown*": 0.15},
    "utter_u": {"mouthPucker": 0.85, "mouthFunnel": 0.25, "jawOpen": 0.12, "mouthClose": 0.08},
    "utter_o": {"mouthFunnel": 0.75, "jawOpen": 0.35, "mouthPucker": 0.2},
    "smile_closed": {"mouthSmile*": 0.75, "cheekSquint*": 0.4, "eyeSquint*": 0.25, "mouthPress*": 0.15},
    "smile_open": {"mouthSmile*": 0.75, "jawOpen": 0.3, "cheekSquint*": 0.45, "eyeSquint*": 0.3,
                   "mouthUpperUp*": 0.3, "mouthLowerDown*": 0.3},
}
NUISANCE = ("browInnerUp*", "browOuterUp*", "eyeBlink*", "eyeSquint*")
WEAK, STRONG = 0.4, 1.0
NOISE_CM = 0.01


@dataclass(frozen=True)
class Ict:
    neutral: np.ndarray  # (N, 3) cm
    identity: np.ndarray  # (100, N, 3)
    blend: dict[str, np.ndarray]  # ARKit name -> (N, 3)
    topology: Mesh


def load_ict(path: Path) -> Ict:
    data = np.load(path)
    names = [str(n) for n in data["expression_names"]]
    blend = {n: data["expression_deltas"][i].astype(np.float64) for i, n in enumerate(names)}
    quads = data["quads"].astype(np.int64)
    neutral = data["neutral"].astype(np.float64)
    return Ict(neutral, data["identity_deltas"].astype(np.float64), blend, Mesh.from_faces(neutral, quads))


@dataclass(frozen=True)
class Person:
    neutral: np.ndarray
    gains: dict[str, float]
    asymmetry: float
    size: float


def make_person(ict: Ict, rng: np.random.Generator) -> Person:
    neutral = ict.neutral + np.tensordot(rng.standard_normal(len(ict.identity)), ict.identity, axes=1)
    height = np.ptp(neutral[:, 1]) / np.ptp(ict.neutral[:, 1])
    gains = {name: float(np.exp(0.2 * rng.standard_normal())) for recipe in RECIPES.values() for name in recipe}
    return Person(neutral, gains, float(0.1 * rng.standard_normal()), float(height))


def _expand(weights: dict[str, float], asymmetry: float) -> dict[str, float]:
    out: dict[str, float] = {}
    for name, w in weights.items():
        if name.endswith("*"):
            out[name[:-1] + "_L"] = out.get(name[:-1] + "_L", 0.0) + w * (1 + asymmetry)
            out[name[:-1] + "_R"] = out.get(name[:-1] + "_R", 0.0) + w * (1 - asymmetry)
        else:
            out[name] = out.get(name, 0.0) + w
    return out


def face(ict: Ict, person: Person, expression: str, intensity: float, nuisance: dict[str, float]) -> np.ndarray:
    """(N, 3) cm: the person's neutral face plus the expression's blendshapes (weights clipped to [0, 1])."""
    if expression == NEUTRAL:
        return person.neutral.copy()
    recipe = {k: intensity * w * person.gains[k] for k, w in RECIPES[expression].items()}
    weights = _expand(recipe, person.asymmetry)
    for k, w in _expand(nuisance, 0.0).items():
        weights[k] = weights.get(k, 0.0) + w
    disp = sum(np.clip(w, 0.0, 1.0) * ict.blend[k] for k, w in weights.items())
    return person.neutral + person.size * disp


def random_nuisance(rng: np.random.Generator) -> dict[str, float]:
    return {k: float(abs(0.08 * rng.standard_normal())) for k in NUISANCE}


def build_split(ict: Ict, people: list[Person], rng: np.random.Generator, tag: str) -> FaceDataset:
    faces, persons, labels = [], [], []
    for i, person in enumerate(people):
        for expression in (NEUTRAL, *EXPRESSIONS):
            x = face(ict, person, expression, rng.uniform(0.7, 1.0), random_nuisance(rng))
            faces.append(x + NOISE_CM * rng.standard_normal(x.shape))
            persons.append(f"{tag}{i:03d}")
            labels.append(expression)
    return FaceDataset(np.stack(faces), np.array(persons), np.array(labels), ict.topology)


class Judge:
    """An independent observer trained on split J: its own PCA of the displacements, then
    a linear judge (multinomial logistic regression over neutral + 6 expressions) and a kernel
    judge (one RBF-kernel SVC per expression, against the rest). The linear judge extrapolates:
    any step along a discriminative direction raises it, on or off the space of real faces. The
    kernel judge's decision value is high only near real examples of the expression."""

    def __init__(self, ds: FaceDataset) -> None:
        disp = ds.displacements()
        self.mean, self.basis, self.variances, _ = fit_pca(disp, 0.998, 60)
        self.classes = [NEUTRAL, *EXPRESSIONS]
        labels = np.array([self.classes.index(e) for e in ds.expressions])
        scores = self.scores(disp)
        self.unit = float(np.sqrt(np.mean(np.sum(scores**2, axis=1))))
        self.linear = LogisticRegression(C=1.0, max_iter=5000).fit(scores, labels)
        self.kernel = {e: SVC(kernel="rbf", C=1.0, gamma="scale", class_weight="balanced").fit(
            scores / self.unit, ds.expressions == e) for e in EXPRESSIONS}

    def scores(self, disp: np.ndarray) -> np.ndarray:
        return (np.atleast_2d(disp) - self.mean) @ self.basis

    def log_odds(self, disp: np.ndarray, target: str) -> np.ndarray:
        """Linear judge: ``z_t - logsumexp(z_others)`` of the multinomial logits, per row."""
        z = self.linear.decision_function(self.scores(disp))
        t = self.classes.index(target)
        others = np.delete(z, t, axis=1)
        top = others.max(axis=1, keepdims=True)
        return z[:, t] - (top[:, 0] + np.log(np.exp(others - top).sum(axis=1)))

    def kernel_decision(self, disp: np.ndarray, target: str) -> np.ndarray:
        """Kernel judge: the target's RBF-SVC decision value (> 0: looks like a real example of it)."""
        return self.kernel[target].decision_function(self.scores(disp) / self.unit)

    def recognised(self, disp: np.ndarray, target: str) -> np.ndarray:
        return self.linear.predict(self.scores(disp)) == self.classes.index(target)

    def mahalanobis(self, disp: np.ndarray) -> np.ndarray:
        return np.sqrt(np.sum(self.scores(disp) ** 2 / self.variances, axis=1))

    def off_model_mm(self, disp: np.ndarray) -> np.ndarray:
        centred = np.atleast_2d(disp) - self.mean
        rest = centred - (centred @ self.basis) @ self.basis.T
        return 10.0 * np.sqrt(np.sum(rest**2, axis=1) / (rest.shape[1] // 3))


def rms_mm(a: np.ndarray, b: np.ndarray) -> float:
    return float(10.0 * np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


@dataclass
class TestFace:
    person: int
    expression: str
    neutral: np.ndarray
    weak: np.ndarray
    strong: np.ndarray


def test_faces(ict: Ict, people: list[Person], rng: np.random.Generator) -> list[TestFace]:
    out = []
    for i, person in enumerate(people):
        for expression in EXPRESSIONS:
            nuisance = random_nuisance(rng)
            out.append(TestFace(i, expression, person.neutral, face(ict, person, expression, WEAK, nuisance),
                                face(ict, person, expression, STRONG, nuisance)))
    return out


METRICS = ("perceptibility", "kernel_perceptibility", "recognised", "distance_mm", "mahalanobis", "off_model_mm",
           "disp_mean_mm", "disp_p95_mm", "disp_max_mm", "svc_decision")


def transform_cases(model, cases: list[TestFace], method: str, q: float, estimate: bool = False, **kw) -> list:
    return [transform_vertices(model, t.weak, t.expression, method, q, neutral=None if estimate else t.neutral, **kw)
            for t in cases]


def metrics(judge: Judge, outs: list, cases: list[TestFace]) -> tuple[dict[str, float], np.ndarray]:
    """Means over the cases of every metric, and the per-case linear-judge log-odds."""
    expression = cases[0].expression
    disp = np.stack([(o.vertices - t.neutral).ravel() for o, t in zip(outs, cases)])
    moved = 10.0 * np.stack([np.linalg.norm(o.vertices - t.weak, axis=1) for o, t in zip(outs, cases)])
    odds = judge.log_odds(disp, expression)
    values = {
        "perceptibility": odds.mean(),
        "kernel_perceptibility": judge.kernel_decision(disp, expression).mean(),
        "recognised": judge.recognised(disp, expression).mean(),
        "distance_mm": np.mean([rms_mm(o.vertices, t.strong) for o, t in zip(outs, cases)]),
        "mahalanobis": judge.mahalanobis(disp).mean(),
        "off_model_mm": judge.off_model_mm(disp).mean(),
        "disp_mean_mm": moved.mean(),
        "disp_p95_mm": np.percentile(moved, 95, axis=1).mean(),
        "disp_max_mm": moved.max(axis=1).mean(),
        "svc_decision": np.mean([o.decision_after for o in outs]),
    }
    return {k: float(v) for k, v in values.items()}, odds


def sweep(model, judge: Judge, tests: list[TestFace], qs: list[float], estimate: bool = False) -> dict:
    """expression -> method -> metric -> list over Q (means over the test people)."""
    out: dict = {}
    for expression in EXPRESSIONS:
        cases = [t for t in tests if t.expression == expression]
        for method in METHODS:
            rows: dict = {k: [] for k in METRICS}
            rows["per_person_perceptibility"] = []
            for q in qs:
                values, odds = metrics(judge, transform_cases(model, cases, method, q, estimate), cases)
                for k, v in values.items():
                    rows[k].append(v)
                rows["per_person_perceptibility"].append(odds.tolist())
            out.setdefault(expression, {})[method] = rows
    return out


def equal_plausibility(model, judge: Judge, tests: list[TestFace], reference: dict) -> dict:
    """Both judges where each transformed face is exactly as plausible as the real strong faces.

    The output moves linearly with Q (``X + Q U w q_unit``), so its Mahalanobis distance in the
    judge's PCA space is the root of a quadratic in Q: we solve for the Q >= 0 that reaches the
    mean Mahalanobis distance of the real strong expressions, per face (Q = 0 if already beyond).
    """
    out: dict = {}
    for expression in EXPRESSIONS:
        cases = [t for t in tests if t.expression == expression]
        target = reference[f"{expression}.strong"]["mahalanobis"]
        for method in METHODS:
            step = transform_cases(model, cases, method, 1.0)
            q_star = []
            for o, t in zip(step, cases):
                z0, z1 = judge.scores(np.stack([(t.weak - t.neutral).ravel(), (o.vertices - t.neutral).ravel()]))
                z0, dz = z0 / np.sqrt(judge.variances), (z1 - z0) / np.sqrt(judge.variances)
                a, b, c = dz @ dz, 2 * z0 @ dz, z0 @ z0 - target**2
                q_star.append(max(0.0, (-b + np.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a)) if a > 0 else 0.0)
            outs = [transform_vertices(model, t.weak, expression, method, q, neutral=t.neutral)
                    for t, q in zip(cases, q_star)]
            values, _ = metrics(judge, outs, cases)
            out.setdefault(expression, {})[method] = {**values, "q": float(np.mean(q_star))}
    return out


def _mean_metrics(model, judge: Judge, tests: list[TestFace], method: str, **kw) -> list[float]:
    """Linear and kernel perceptibility, Mahalanobis and distance at Q = 1, averaged over the expressions."""
    values = []
    for e in EXPRESSIONS:
        cases = [t for t in tests if t.expression == e]
        values.append(metrics(judge, transform_cases(model, cases, method, 1.0, **kw), cases)[0])
    return [float(np.mean([v[k] for v in values]))
            for k in ("perceptibility", "kernel_perceptibility", "mahalanobis", "distance_mm")]


def sensitivity(train_ds: FaceDataset, judge: Judge, tests: list[TestFace], cs: list[float | None],
                neighbours: list[int], shrinkages: list[float | None]) -> tuple[list[list], list[list]]:
    """Rows for the SVM method with other C and m = n, and for the Fisher method with other shrinkage."""
    svm_rows, fisher_rows = [], []
    for c in cs:
        model = train_face_model(train_ds, TrainSettings(svm_c=c))
        for k in neighbours:
            svm_rows.append(["auto" if c is None else c, k, sum(model.meta["support_vectors"].values()),
                             float(np.mean(list(model.meta["svm_training_accuracy"].values()))),
                             *_mean_metrics(model, judge, tests, "svm", m=k, n=k)])
    for shrinkage in shrinkages:
        model = train_face_model(train_ds, TrainSettings(fisher_shrinkage=shrinkage))
        fisher_rows.append(["Ledoit-Wolf" if shrinkage is None else shrinkage,
                            *_mean_metrics(model, judge, tests, "fisher")])
    return svm_rows, fisher_rows


def reference_rows(judge: Judge, tests: list[TestFace]) -> dict:
    """The judge on the real weak and strong expressions (what the transforms are compared against)."""
    out = {}
    for expression in EXPRESSIONS:
        cases = [t for t in tests if t.expression == expression]
        for name in ("weak", "strong"):
            disp = np.stack([(getattr(t, name) - t.neutral).ravel() for t in cases])
            out[f"{expression}.{name}"] = {
                "perceptibility": float(judge.log_odds(disp, expression).mean()),
                "kernel_perceptibility": float(judge.kernel_decision(disp, expression).mean()),
                "recognised": float(judge.recognised(disp, expression).mean()),
                "mahalanobis": float(judge.mahalanobis(disp).mean()),
                "off_model_mm": float(judge.off_model_mm(disp).mean()),
            }
    return out


def pick_persons(people: list[Person]) -> list[int]:
    """The paper's persons A-D: k-means (4) of the neutral faces in PCA space, farthest from the origin in each."""
    flat = np.stack([p.neutral.ravel() for p in people])
    mean, basis, _, _ = fit_pca(flat, 0.998, 20)
    coords = (flat - mean) @ basis
    labels = KMeans(n_clusters=4, n_init=10, random_state=0).fit_predict(coords)
    radius = np.linalg.norm(coords, axis=1)
    picks = [int(np.flatnonzero(labels == c)[np.argmax(radius[labels == c])]) for c in range(4)]
    return sorted(picks)


# ------------------------------------------------------------------------------------ timing

def _median_ms(fn, repeats: int) -> float:
    return timed(fn, repeats, warmup=1).median_ms


def timings(model, train_ds: FaceDataset, sample: TestFace, quick: bool) -> dict:
    """Speed: training on the 280 meshes, transforms of one face, mesh I/O, the preview."""
    reps = 15 if quick else 60
    train = timed(lambda: train_face_model(train_ds), 1 if quick else 3)
    basis, x = model.morph.basis, sample.weak.ravel()
    obj = write_mesh(model.morph.topology.with_vertices(sample.weak), "obj")
    ply = write_mesh(model.morph.topology.with_vertices(sample.weak), "ply")
    mesh = read_mesh(obj, "a.obj")

    @single_threaded()  # as the engine runs its products
    def baseline() -> None:
        basis @ (basis.T @ x)

    def transform(method: str, **kw):
        return lambda: transform_vertices(model, sample.weak, "smile_open", method, 1.0, **kw)

    out = {
        "train_s": train.median,
        "baseline_matmul_ms": _median_ms(baseline, reps),
        "transform_ms": _median_ms(transform("svm", neutral=sample.neutral), reps),
        "transform_fisher_ms": _median_ms(transform("fisher", neutral=sample.neutral), reps),
        "transform_estimated_neutral_ms": _median_ms(transform("svm"), reps),
        "transform_mesh_checked_ms": _median_ms(lambda: transform_mesh(model, mesh, "smile_open", "svm", 1.0), reps),
        "obj_read_ms": _median_ms(lambda: read_mesh(obj, "a.obj"), reps),
        "obj_rewrite_ms": _median_ms(lambda: replace_vertices(obj, sample.weak, "a.obj"), reps),
        "ply_read_ms": _median_ms(lambda: read_mesh(ply, "a.ply"), reps),
        "preview_ms": _median_ms(lambda: preview_png(sample.weak, sample.strong, model.morph.topology.triangles()),
                                 max(3, reps // 5)),
        "n_vertices": int(model.morph.n_vertices),
        "n_train_meshes": int(len(train_ds.vertices)),
    }
    if not quick:
        for fmt in ("ply", "obj"):
            zipped = write_dataset_zip(train_ds, fmt)
            out[f"import_{fmt}_zip_s"] = timed(lambda: load_dataset_zip(zipped)).median
    return out


# ------------------------------------------------------------------------------------ plots

def write_plots(qs: list[float], results: dict, reference: dict, fig56: dict, examples: np.ndarray | None,
                out_dir: Path) -> list[str]:
    """The charts named in RESULTS.md (and the example sheet, when given); returns their names."""
    files = []
    for metric, label, name in (("perceptibility", "linear judge log-odds", "faces_perceptibility.png"),
                                ("kernel_perceptibility", "kernel judge decision", "faces_kernel_judge.png"),
                                ("distance_mm", "RMS mm to the real strong face", "faces_distance.png"),
                                ("mahalanobis", "Mahalanobis, judge PCA", "faces_plausibility.png")):
        fig, axes = plots.panels(len(EXPRESSIONS), 3)
        for ax, e in zip(axes, EXPRESSIONS):
            plots.line_chart(ax, e, {m: (qs, results[e][m][metric], COLOURS[m]) for m in METHODS}, "Q", label)
        plots.save(fig, out_dir / name)
        files.append(name)
    fig, axes = plots.panels(len(EXPRESSIONS), 3)
    for ax, e in zip(axes, EXPRESSIONS):
        plots.line_chart(ax, e, {m: (results[e][m]["mahalanobis"], results[e][m]["perceptibility"], COLOURS[m])
                                 for m in METHODS}, "Mahalanobis (dashed: real strong faces)", "linear judge log-odds",
                         reference[f"{e}.strong"]["mahalanobis"])
    plots.save(fig, out_dir / "faces_tradeoff.png")
    files.append("faces_tradeoff.png")
    fig, axes = plots.panels(2, 2, (5.2, 3.2))
    for ax, e in zip(axes, ("smile_closed", "smile_open")):
        plots.bar_chart(ax, f"{e}: persons A-D", fig56["persons"],
                        {k: (fig56[e][k], COLOURS[k]) for k in ("none", "fisher", "svm")}, "linear judge log-odds")
    plots.save(fig, out_dir / "faces_fig5_6.png")
    files.append("faces_fig5_6.png")
    if examples is not None:
        cv2.imwrite(str(out_dir / "faces_examples.png"), examples)
        files.append("faces_examples.png")
    return files


def replot(out_dir: Path = RESULTS_DIR) -> list[str]:
    """Redraw the charts from the last run's ``faces.json`` (the example sheet needs the model: kept)."""
    saved = json.loads((out_dir / "faces.json").read_text())
    return write_plots(saved["config"]["qs"], saved["sweep"], saved["reference"], saved["fig5_6"], None, out_dir)


def example_sheet(model, tests: list[TestFace], person: int, q: float, size: int = 200) -> np.ndarray:
    """Rows: expressions; columns: input (weak), Fisher, SVM, the real strong face (like Figs. 1-3)."""
    tris = model.morph.topology.triangles()
    rows = []
    for t in (t for t in tests if t.person == person):
        faces = [t.weak,
                 transform_vertices(model, t.weak, t.expression, "fisher", q, neutral=t.neutral).vertices,
                 transform_vertices(model, t.weak, t.expression, "svm", q, neutral=t.neutral).vertices,
                 t.strong]
        view = frame(faces, size)
        tiles = [render(f, tris, size, view) for f in faces]
        for tile, label in zip(tiles, (t.expression, f"Fisher Q={q:g}", f"SVM Q={q:g}", "real strong")):
            cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(rows, axis=0)


# ------------------------------------------------------------------------------------ report

def flat_results(qs: list[float], results: dict, estimated: dict, plausible: dict) -> dict:
    """The ``<expression>.<method>.<measure>`` keys of faces.json."""
    i1 = qs.index(1.0)
    flat: dict = {}
    for e in EXPRESSIONS:
        for m in METHODS:
            r = results[e][m]
            best = int(np.argmin(r["distance_mm"]))
            for metric in METRICS:
                flat[f"{e}.{m}.{metric}_at_q1"] = r[metric][i1]
            flat[f"{e}.{m}.best_distance_mm"] = r["distance_mm"][best]
            flat[f"{e}.{m}.best_q"] = qs[best]
            flat[f"{e}.{m}.perceptibility_at_q1_estimated_neutral"] = estimated[e][m]["perceptibility"][0]
            for metric in ("perceptibility", "kernel_perceptibility", "distance_mm", "q"):
                flat[f"{e}.{m}.{metric}_at_real_plausibility"] = plausible[e][m][metric]
    return flat


def verdict(flat: dict) -> tuple[dict, str]:
    def count(key: str, better: str) -> list[str]:
        sign = 1 if better == "higher" else -1
        return [e for e in EXPRESSIONS if sign * (flat[f"{e}.svm.{key}"] - flat[f"{e}.fisher.{key}"]) > 0]

    wins = {
        "linear_q1": count("perceptibility_at_q1", "higher"),
        "kernel_q1": count("kernel_perceptibility_at_q1", "higher"),
        "plausible_q1": count("mahalanobis_at_q1", "lower"),
        "linear_equal_plausibility": count("perceptibility_at_real_plausibility", "higher"),
        "kernel_equal_plausibility": count("kernel_perceptibility_at_real_plausibility", "higher"),
        "closer_to_real": count("best_distance_mm", "lower"),
    }
    names = lambda v: f"{len(v)}/6 ({', '.join(v) or 'none'})"  # noqa: E731
    text = (
        f"SVM vs Fisher. At Q = 1 (the same step length) the SVM output is more perceptible for "
        f"{names(wins['linear_q1'])} by the linear judge and {names(wins['kernel_q1'])} by the kernel judge, "
        f"and more plausible (lower Mahalanobis) for {names(wins['plausible_q1'])}. At equal plausibility (each "
        f"face moved until it is as far from the training distribution as the real strong faces) the SVM output "
        f"is more perceptible for {names(wins['linear_equal_plausibility'])} (linear judge) and "
        f"{names(wins['kernel_equal_plausibility'])} (kernel judge). Over the Q sweep it comes closer to the "
        f"person's real strong expression for {names(wins['closer_to_real'])}."
    )
    return {f"svm_wins.{k}": len(v) for k, v in wins.items()}, text


def markdown(qs: list[float], results: dict, reference: dict, plausible: dict, fig56: dict, speed: dict,
             sensitivity_rows: tuple[list[list], list[list]], config: dict, flat: dict,
             verdict_text: str) -> str:
    i1 = qs.index(1.0)
    rows, eq_rows = [], []
    for e in EXPRESSIONS:
        for m in METHODS:
            r = results[e][m]
            rows.append([e, m, r["perceptibility"][0], r["perceptibility"][i1], r["kernel_perceptibility"][i1],
                         r["recognised"][i1], r["distance_mm"][0], r["distance_mm"][i1], flat[f"{e}.{m}.best_q"],
                         flat[f"{e}.{m}.best_distance_mm"], r["mahalanobis"][i1], r["off_model_mm"][i1],
                         r["disp_p95_mm"][i1], r["disp_max_mm"][i1]])
            p = plausible[e][m]
            eq_rows.append([e, m, reference[f"{e}.strong"]["mahalanobis"], p["q"], p["perceptibility"],
                            p["kernel_perceptibility"], p["distance_mm"],
                            flat[f"{e}.{m}.perceptibility_at_q1_estimated_neutral"]])
    ref_rows = [[e, reference[f"{e}.weak"]["perceptibility"], reference[f"{e}.strong"]["perceptibility"],
                 reference[f"{e}.weak"]["kernel_perceptibility"], reference[f"{e}.strong"]["kernel_perceptibility"],
                 reference[f"{e}.strong"]["recognised"], reference[f"{e}.strong"]["mahalanobis"],
                 reference[f"{e}.strong"]["off_model_mm"]] for e in EXPRESSIONS]
    fig_rows = [[e, p, fig56[e]["none"][k], fig56[e]["fisher"][k], fig56[e]["svm"][k]]
                for e in ("smile_closed", "smile_open") for k, p in enumerate(fig56["persons"])]
    speed_rows = [[k, round(v, 3) if isinstance(v, float) else v] for k, v in speed.items()]
    return "\n\n".join([
        f"ICT-FaceKit faces ({speed['n_vertices']} vertices, cm): model trained on {config['train_people']} people "
        f"x 7 = {config['train_people'] * 7} meshes, judges on {config['judge_people']} other people, tested on "
        f"{config['test_people']} held-out people. Input: each expression at intensity {WEAK}; reference: the same "
        f"person's expression at {STRONG}; X_neutral: the person's neutral face. Q is in units of the model's "
        f"typical expression size (q_unit = {config['q_unit']:.1f} cm in the 3N-space). Model K = {config['k']}, "
        f"judge K = {config['judge_k']}; SVM defaults: C per impression (the softest with 90 % balanced "
        f"training accuracy: {config['svm_c']}), m = n = 10.",
        "**" + verdict_text + "**",
        "Per expression and method, means over the test people (linear = judge log-odds of the target; kernel = "
        "RBF-SVC decision value; distances and moves in mm; off-model = RMS part of the displacement outside the "
        "judge's PCA space):",
        md_table(["expression", "method", "linear Q=0", "linear Q=1", "kernel Q=1", "recognised Q=1", "dist Q=0",
                  "dist Q=1", "best Q", "dist best Q", "Mahalanobis Q=1", "off-model Q=1", "p95 move Q=1",
                  "max move Q=1"], rows),
        "At equal plausibility (Mahalanobis of each output = that of the real strong faces), and the linear judge "
        "at Q = 1 with the neutral face estimated from the input (the service's default without a neutral mesh):",
        md_table(["expression", "method", "target Mahalanobis", "mean Q", "linear", "kernel", "dist",
                  "linear Q=1, estimated neutral"], eq_rows),
        "The judges on the real faces (calibration):",
        md_table(["expression", "linear weak", "linear strong", "kernel weak", "kernel strong", "recognised strong",
                  "Mahalanobis strong", "off-model strong"], ref_rows),
        "SVM method at Q = 1 for other C and m = n (means over the six expressions; auto = the default):",
        md_table(["C", "m = n", "support vectors", "SVC train accuracy", "linear", "kernel", "Mahalanobis",
                  "dist"], sensitivity_rows[0]),
        "Fisher method at Q = 1 for other shrinkage of the within-class scatter (1 = the plain difference of "
        "the class means); the default is Ledoit-Wolf:",
        md_table(["shrinkage", "linear", "kernel", "Mahalanobis", "dist"], sensitivity_rows[1]),
        "Figs. 5-6 redone with the linear judge (persons A-D chosen as in the paper; Q = 1):",
        md_table(["expression", "person", "non-emphasised", "Fisher", "SVM"], fig_rows),
        "Speed (medians; `baseline_matmul_ms` = the two products with the basis every transform needs, timed "
        "in the same run; the target is <= 20 ms per transform of a 10k-vertex mesh and <= 5 s to train on 280):",
        md_table(["measure", "value"], speed_rows),
        "Plots in `benchmarks/results/`: `faces_perceptibility.png`, `faces_kernel_judge.png`, "
        "`faces_distance.png`, `faces_plausibility.png` (against Q; Fisher red, SVM blue), `faces_tradeoff.png` "
        "(linear judge against Mahalanobis), `faces_fig5_6.png`, `faces_examples.png` (input, Fisher, SVM, real "
        "strong at Q = 1).",
    ])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer people, fewer Q values, fewer repeats")
    parser.add_argument("--plots-only", action="store_true", help="redraw the charts from results/faces.json")
    args = parser.parse_args(argv)
    if args.plots_only:
        print("\n".join(replot()))
        return 0
    path = dataset("face3d", "ict", "ict_face_area.npz")
    if path is None:
        print("skipped: face3d/ict/ict_face_area.npz not found under $SWEEPCAST_DATA (ICT-FaceKit)")
        return 0
    ict = load_ict(path)
    n_train, n_judge, n_test = (20, 20, 8) if args.quick else (40, 40, 20)
    qs = [0.0, 0.5, 1.0, 2.0] if args.quick else [0.0, 0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0]
    rng = np.random.default_rng(2024)
    people = [make_person(ict, rng) for _ in range(n_train + n_judge + n_test)]
    train_ds = build_split(ict, people[:n_train], rng, "a")
    judge = Judge(build_split(ict, people[n_train:n_train + n_judge], rng, "j"))
    test_people = people[n_train + n_judge:]
    tests = test_faces(ict, test_people, rng)
    print(f"training on {len(train_ds.vertices)} meshes ...", flush=True)
    model = train_face_model(train_ds)
    print(f"model K={model.morph.n_components}, judge K={judge.basis.shape[1]}; sweeping Q ...", flush=True)
    results = sweep(model, judge, tests, qs)
    estimated = sweep(model, judge, tests, [1.0], estimate=True)
    reference = reference_rows(judge, tests)
    plausible = equal_plausibility(model, judge, tests, reference)
    print("sensitivity to C, m, n ...", flush=True)
    sens = sensitivity(train_ds, judge, tests, [None, 0.1, 1.0] if args.quick else [None, 0.1, 1.0, 10.0, 100.0],
                       [1, 5] if args.quick else [1, 3, 5, 10], [None, 0.1, 0.5, 1.0])
    persons = pick_persons(test_people)
    fig56: dict = {"persons": ["A", "B", "C", "D"], "indices": persons}
    for e in ("smile_closed", "smile_open"):
        per = {m: np.array(results[e][m]["per_person_perceptibility"]) for m in METHODS}
        fig56[e] = {"none": per["svm"][0, persons].tolist(), "fisher": per["fisher"][qs.index(1.0), persons].tolist(),
                    "svm": per["svm"][qs.index(1.0), persons].tolist()}
    print("timing ...", flush=True)
    speed = timings(model, train_ds, tests[0], args.quick)
    config = {"train_people": n_train, "judge_people": n_judge, "test_people": n_test, "qs": qs,
              "k": model.morph.n_components, "judge_k": int(judge.basis.shape[1]), "q_unit": model.q_unit,
              "svm_c": model.meta["svm_c"],
              "weak": WEAK, "strong": STRONG, "recipes": RECIPES, "quick": args.quick}
    flat = flat_results(qs, results, estimated, plausible)
    wins, verdict_text = verdict(flat)
    md = markdown(qs, results, reference, plausible, fig56, speed, sens, config, flat, verdict_text)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    plots = write_plots(qs, results, reference, fig56, example_sheet(model, tests, persons[0], 1.0), RESULTS_DIR)
    payload = {**flat, **wins, "transform_ms": speed["transform_ms"], "train_s": speed["train_s"], "speed": speed,
               "config": config, "sweep": results, "equal_plausibility": plausible, "reference": reference,
               "sensitivity": {"svm": sens[0], "fisher": sens[1]}, "fig5_6": fig56, "plots": plots}
    publish("faces", payload, md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
