"""The docs match the program: generated tables equal what docs/results/ renders to, links resolve in a clone.

That docs/results/ equals what the experiments print now is checked by `.ci/run`
(`python tools/docs_results.py check --run` re-runs the seed-0 experiments)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _tool():
    spec = importlib.util.spec_from_file_location("docs_results", ROOT / "tools" / "docs_results.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_generated_block_is_what_docs_results_renders():
    tool = _tool()
    names = {m.group("name") for p in tool.DOCS for m in tool.BLOCK.finditer(p.read_text())}
    assert {"exp2-seed0-table5", "exp2-seed0-table6", "exp1-seed0"} <= names   # the README's tables are generated
    assert names <= set(tool.blocks())
    assert tool.differences() == []


def test_the_real_motion_tables_are_generated_with_one_header_each():
    # docs/pipeline.md's fr1_xyz / fr2_desk tables were copied by hand once, with their header line twice
    tool = _tool()
    text = (ROOT / "docs" / "pipeline.md").read_text()
    bodies = {m.group("name"): m.group("body") for m in tool.BLOCK.finditer(text) if m.group("name").startswith("motion-")}
    assert set(bodies) == {f"motion-seed0-{name}-{gt}" for name, *_ in tool.MOTIONS for gt in tool.MOTION_GTS}
    for body in bodies.values():
        assert body.count("| tracker |") == 1
        assert [line.split(" |")[0] for line in body.splitlines()[2:]] == [
            f"| {t}" for t in ("T1", "T2", "T3", "T4", "T5", "T6", "T7", "T7L", "T8")]


def test_a_changed_number_is_found(tmp_path, monkeypatch):
    """The check can fail: a block edited by hand differs from its rendering."""
    tool = _tool()
    readme = tmp_path / "README.md"
    text = (ROOT / "README.md").read_text()
    m = next(tool.BLOCK.finditer(text))
    body = m.group("body")
    digit = re.search(r"\d\.\d", body)
    assert digit is not None
    edited = body[: digit.start()] + str((int(body[digit.start()]) + 1) % 10) + body[digit.start() + 1:]
    readme.write_text(text[: m.start("body")] + edited + text[m.end("body"):])
    monkeypatch.setattr(tool, "DOCS", [readme])
    monkeypatch.setattr(tool, "ROOT", tmp_path)
    assert tool.differences() == ["README.md"]


@pytest.mark.parametrize("doc", DOC_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve_in_a_clone(doc):
    """A user's clone has only the repository: no link or path into ../shared, every relative link exists."""
    text = doc.read_text()
    assert "../shared" not in text
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if re.match(r"[a-z]+://|mailto:", target):
            continue
        assert (doc.parent / target).exists(), f"{doc.relative_to(ROOT)} links to {target}, which does not exist"
