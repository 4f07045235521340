"""The ``sweepcast`` command's parser: every verb listed, the service's own verbs parsed without the engines."""
from __future__ import annotations

import subprocess
import sys


def test_help_lists_the_service_and_every_engine_verb():
    out = subprocess.run([sys.executable, "-m", "app", "--help"], capture_output=True, text=True, check=True).stdout
    for verb in ("serve", "worker", "warmup", "kernel-env", "live", "keys", "orient", "depth", "face", "render", "reconstruct"):
        assert verb in out


def test_the_entrypoint_verb_imports_no_engine(tmp_path):
    """The Ray head's container start runs ``sweepcast kernel-env`` (then ``ray start``): it must not import the
    engines (a second and a half of CPU, beside the other containers booting at once on 2 cores)."""
    code = ("import sys; from app.cli import main; "
            f"main(['kernel-env', '--data-dir', {str(tmp_path)!r}]); "
            "loaded = [m for m in sys.modules if m.startswith(('workers.drone', 'workers.faces', 'workers.sweep'))]; "
            "assert not loaded, loaded")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "export NUMBA_CACHE_DIR=" in out


def test_each_engine_module_adds_the_verbs_the_parser_expects_of_it():
    """``ENGINE_CLIS`` says which verbs each module adds, so that a command line naming one imports that module
    alone: a module that adds another verb would be missing from such a command line's parser."""
    import argparse
    import importlib

    from app.cli import ENGINE_CLIS

    for module, verbs in ENGINE_CLIS.items():
        parser = argparse.ArgumentParser()
        sub = parser.add_subparsers()
        importlib.import_module(module).register(sub)
        assert tuple(sub.choices) == verbs, module


def test_an_engine_verb_imports_no_other_engine(tmp_path):
    """``sweepcast orient`` over a library parses its command line without importing the renderer, the drone and
    the face engines (a second and a half of CPU before the first photo)."""
    code = ("import sys; from app.cli import build_parser; "
            f"args = build_parser(command='orient').parse_args(['orient', {str(tmp_path)!r}, '--jobs', '1']); "
            "assert args.jobs == 1; "
            "loaded = [m for m in sys.modules if m.startswith(('workers.drone', 'workers.faces', 'workers.sweep', "
            "'workers.depth', 'numba'))]; "
            "assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
