"""``sweepcast face ...``: train a face model, transform a mesh, write the synthetic training set.

    sweepcast face train [--dataset faces.zip] [--out face_model.npz]
    sweepcast face transform MESH --impression smile_open --method svm --q 1.5 [--model PATH]
                                  [--neutral MESH] [--out PATH] [--preview PNG]
    sweepcast face synth --out faces.zip          (the synthetic set in the importer's zip format)

Without ``--model``, ``transform`` uses the default model (trained from the synthetic generator on
first use and cached at ``$SWEEPCAST_FACE_MODEL`` or ``~/.cache/sweepcast/faces/default_model.npz``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from pydantic import ValidationError

from workers.common.cliutil import ProgressBar, format_table
from workers.common.validation import describe_errors
from workers.faces.dataset import load_dataset_zip, write_dataset_zip
from workers.faces.errors import FaceInputError
from workers.faces.job import (FaceTrainParams, FaceTransformParams, ensure_default_model, load_model,
                               transform_mesh_bytes)
from workers.faces.synthetic import generate_dataset
from workers.faces.train import train_face_model


def default_model_path() -> Path:
    """Where the CLI caches the default (synthetic) model."""
    env = os.environ.get("SWEEPCAST_FACE_MODEL")
    if env:
        return Path(env)
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "sweepcast" / "faces" / "default_model.npz"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``face`` command and its verbs to a ``sweepcast`` sub-command parser."""
    face = subparsers.add_parser("face", help="3D face transformer: morphable model + SVM/Fisher impression vectors")
    verbs = face.add_subparsers(dest="face_verb", required=True, metavar="{train,transform,synth}")

    train = verbs.add_parser("train", help="train a face model from a dataset zip or synthetic faces")
    train.add_argument("--dataset", type=Path, help="zip with manifest.csv (person,expression,file) and meshes")
    train.add_argument("--people", type=int, default=40, help="synthetic faces: number of people (default 40)")
    train.add_argument("--seed", type=int, default=0, help="synthetic faces: random seed")
    train.add_argument("--variance", type=float, default=0.998, help="PCA explained variance (default 0.998)")
    train.add_argument("--components", type=int, default=60, help="at most this many PCA components")
    train.add_argument("--c", type=float, help="SVC C on unit-RMS scores (default: chosen per impression)")
    train.add_argument("--m", type=int, default=10, help="default positive neighbours of eq. 5")
    train.add_argument("--n", type=int, default=10, help="default negative neighbours of eq. 5")
    train.add_argument("--out", "-o", type=Path, default=Path("face_model.npz"), help="model file to write")
    train.set_defaults(func=_train)

    tr = verbs.add_parser("transform", help="emphasise an impression on a registered face mesh (OBJ/PLY)")
    tr.add_argument("mesh", type=Path)
    tr.add_argument("--impression", required=True, help="e.g. smile_open, utter_a")
    tr.add_argument("--method", choices=("svm", "fisher"), default="svm")
    tr.add_argument("--q", type=float, default=1.0, help="intensity Q (units of a typical expression)")
    tr.add_argument("--model", type=Path, help="model .npz (default: the synthetic default model)")
    tr.add_argument("--neutral", type=Path, help="the same person's neutral face (default: the model's mean)")
    tr.add_argument("--m", type=int, help="positive neighbours of eq. 5 (default: the model's)")
    tr.add_argument("--n", type=int, help="negative neighbours of eq. 5 (default: the model's)")
    tr.add_argument("--mean-neutral", action="store_true",
                    help="without --neutral, use the model's mean neutral face instead of estimating it")
    tr.add_argument("--eq9", action="store_true", help="rebuild from the K components only (eq. 9 as written)")
    tr.add_argument("--out", "-o", type=Path, help="output mesh (default: MESH_<impression>_<method>.<ext>)")
    tr.add_argument("--preview", type=Path, help="also write a side-by-side preview PNG here")
    tr.set_defaults(func=_transform)

    synth = verbs.add_parser("synth", help="write the synthetic training faces as a dataset zip")
    synth.add_argument("--people", type=int, default=40)
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--format", choices=("obj", "ply"), default="obj")
    synth.add_argument("--out", "-o", type=Path, default=Path("synthetic_faces.zip"))
    synth.set_defaults(func=_synth)


def _fail(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


def _validation_message(exc: ValidationError) -> str:
    return describe_errors(exc)


def _train(args: argparse.Namespace) -> int:
    try:
        params = FaceTrainParams(source="dataset" if args.dataset else "synthetic", people=args.people,
                                 seed=args.seed, variance=args.variance, max_components=args.components,
                                 svm_c=args.c, m=args.m, n=args.n)
    except ValidationError as exc:
        return _fail(_validation_message(exc))
    bar = ProgressBar("face train")
    try:
        if args.dataset:
            if not args.dataset.is_file():
                return _fail(f"no such dataset zip: {args.dataset}")
            dataset = load_dataset_zip(args.dataset, progress=lambda f, s: bar(0.5 * f, s))
        else:
            dataset = generate_dataset(params.people, params.seed)
        model = train_face_model(dataset, params.settings(), progress=lambda f, s: bar(0.5 + 0.5 * f, s))
    except FaceInputError as exc:
        bar.close()
        return _fail(str(exc))
    bar.close()
    model.save(args.out)
    meta = model.meta
    rows = [[imp, meta["support_vectors"][imp], meta["svm_training_accuracy"][imp]] for imp in model.impressions]
    print(format_table(["impression", "support vectors", "SVC training accuracy"], rows))
    print(f"{meta['n_faces_trained']} faces of {meta['n_people']} people, K = {model.morph.n_components} "
          f"({model.morph.explained_ratio():.2%} of the variance), {meta['train_seconds']:.2f} s -> {args.out}")
    return 0


def _transform(args: argparse.Namespace) -> int:
    try:
        params = FaceTransformParams(impression=args.impression, method=args.method, q=args.q, m=args.m,
                                     n=args.n, keep_detail=not args.eq9,
                                     estimate_neutral=not args.mean_neutral)
    except ValidationError as exc:
        return _fail(_validation_message(exc))
    if not args.mesh.is_file():
        return _fail(f"no such mesh file: {args.mesh}")
    if args.neutral and not args.neutral.is_file():
        return _fail(f"no such neutral mesh file: {args.neutral}")
    try:
        model = load_model(args.model) if args.model else ensure_default_model(default_model_path())
        out = transform_mesh_bytes(
            model, args.mesh.read_bytes(), args.mesh.name, **params.model_dump(),
            neutral_bytes=args.neutral.read_bytes() if args.neutral else None,
            neutral_filename=args.neutral.name if args.neutral else None,
        )
    except FaceInputError as exc:
        return _fail(str(exc))
    target = args.out or args.mesh.with_name(f"{args.mesh.stem}_{params.impression}_{params.method}{args.mesh.suffix}")
    target.write_bytes(out.mesh)
    if args.preview:
        args.preview.write_bytes(out.preview_png)
    print(json.dumps({"output": str(target), **out.info}, indent=2))
    return 0


def _synth(args: argparse.Namespace) -> int:
    try:
        params = FaceTrainParams(source="synthetic", people=args.people, seed=args.seed)
    except ValidationError as exc:
        return _fail(_validation_message(exc))
    dataset = generate_dataset(params.people, params.seed)
    args.out.write_bytes(write_dataset_zip(dataset, args.format))
    print(f"{len(dataset.vertices)} faces of {params.people} people -> {args.out}")
    return 0
