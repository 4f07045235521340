"""The benchmarks' section runner (benchmarks/_report.py): --only re-runs some sections and keeps the others."""
import json

import pytest

from benchmarks import _report


@pytest.fixture
def toy(tmp_path, monkeypatch):
    monkeypatch.setattr(_report, "RESULTS_DIR", tmp_path)
    monkeypatch.setattr(_report, "RESULTS_MD", tmp_path / "RESULTS.md")
    sections = _report.Sections("toy", "A toy benchmark.")
    sections.section("a", "first")(lambda args: {"a": 10})
    sections.section("b", "second", keys=("b", "b_extra"))(lambda args: {"b": 20, "b_extra": 21})
    return sections, tmp_path


def markdown(results, kept):
    return f"a={results.get('a')} b={results.get('b')}; kept: {','.join(kept) or '-'}"


def test_only_keeps_the_other_sections_of_the_previous_results(toy):
    sections, folder = toy
    (folder / "toy.json").write_text(json.dumps({"meta": {"date": "D0", "command": "python benchmarks/toy.py --only a"},
                                                 "a": 1, "b": 2, "stale": 3}))
    assert sections.main(markdown, ["--only", "b", "--settle", "0"]) == 0
    out = json.loads((folder / "toy.json").read_text())
    assert (out["a"], out["b"], out["b_extra"]) == (1, 20, 21)
    assert "stale" not in out
    assert out["runs"]["a"] == {"date": "D0", "command": "python benchmarks/toy.py --only a"}
    md = (folder / "RESULTS.md").read_text()
    assert "a=1 b=20; kept: a" in md and "- a: from the run of D0" in md and "Measured in this run: b." in md


def test_a_full_run_replaces_every_section_and_list_names_them(toy, capsys):
    sections, folder = toy
    assert sections.main(markdown, ["--settle", "0"]) == 0
    out = json.loads((folder / "toy.json").read_text())
    assert (out["a"], out["b"]) == (10, 20) and set(out["runs"]) == {"a", "b"}
    assert "kept: -" in (folder / "RESULTS.md").read_text()
    assert sections.main(markdown, ["--list"]) == 0
    assert capsys.readouterr().out.split() == ["a", "first", "b", "second"]


def test_an_unknown_section_is_refused(toy):
    sections, _ = toy
    with pytest.raises(SystemExit):
        sections.main(markdown, ["--only", "c"])


def test_parts_publish_their_own_results_whole_and_only_the_chosen_ones_run(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(_report, "RESULTS_DIR", tmp_path)
    monkeypatch.setattr(_report, "RESULTS_MD", tmp_path / "RESULTS.md")
    parts = _report.Sections("toy", "A toy benchmark of two parts.")
    parts.parser.add_argument("--planes", type=int, default=48)
    ran = []
    parts.part("speed", "how fast", lambda args: (ran.append("speed") or {"fps": 30}, "fps 30"))
    parts.part("sizes", "which size", lambda args: (ran.append("sizes") or {"size": args.planes}, f"{args.planes} planes"),
               results=lambda args: "toy_sizes" if args.planes == 48 else f"toy_sizes_p{args.planes}")
    (tmp_path / "toy_speed.json").write_text(json.dumps({"fps": 1, "old": True}))
    assert parts.main(argv=["--only", "sizes", "--planes", "64", "--settle", "0"]) == 0
    assert ran == ["sizes"] and json.loads((tmp_path / "toy_sizes_p64.json").read_text())["size"] == 64
    assert json.loads((tmp_path / "toy_speed.json").read_text()) == {"fps": 1, "old": True}  # not chosen: untouched
    assert parts.main(argv=["--settle", "0"]) == 0
    speed = json.loads((tmp_path / "toy_speed.json").read_text())
    assert ran == ["sizes", "speed", "sizes"] and speed["fps"] == 30 and "old" not in speed
    md = (tmp_path / "RESULTS.md").read_text()
    assert "## toy_speed" in md and "fps 30" in md and "## toy_sizes\n" in md and "## toy_sizes_p64" in md
    assert not (tmp_path / "toy.json").exists()
    assert parts.main(argv=["--list"]) == 0
    assert capsys.readouterr().out.split() == ["speed", "how", "fast", "sizes", "which", "size"]
    parts.part("promise", "a check", lambda args: ({"all_404": False}, "not met"), check=lambda r: r["all_404"])
    assert parts.main(argv=["--only", "promise", "--settle", "0"]) == 1  # published, and the exit status says so
    assert json.loads((tmp_path / "toy_promise.json").read_text())["all_404"] is False


def test_load_note_names_other_work_only_after_a_settle_wait():
    from benchmarks._timing import load_note

    assert "other work was running" not in load_note(3.0, 3.5)
    assert "other work was running" in load_note({"before": 3.0, "settled": 2.0, "waited_s": 180.0}, 2.5)
    assert "other work" not in load_note({"before": 3.0, "settled": 0.3, "waited_s": 90.0}, 1.0)
