"""The generated kernel's file is found from a digest of its inputs without generating it
(issue 34), and is generated again whenever that note cannot be trusted."""

from __future__ import annotations

from omnibench.model import kernel
from omnibench.model.terms import layout


def test_kernel_key_from_its_inputs_without_generating(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("OMNIBENCH_CACHE", str(tmp_path))
    lay = layout()
    key, src = kernel._source_key(lay)
    assert src is not None and key == kernel._digest(src, lay)  # first time: generated, the usual key
    folder = kernel._cache_dir()
    assert not (folder / f"omnibench_kernel_{key}.py").exists()
    key2, src2 = kernel._source_key(lay)
    assert key2 == key and src2 is not None  # the note alone is not trusted: no kernel file yet
    (folder / f"omnibench_kernel_{key}.py").write_text(src)
    assert kernel._source_key(lay) == (key, None)  # inputs seen, file there: no generation
    note = next(folder.glob("omnibench_kernel_inputs_*.key"))
    note.write_text("not a key")
    assert kernel._source_key(lay) == (key, src)  # a spoiled note: generated again
    assert kernel._source_key(lay) == (key, None)


def test_kernel_inputs_key_changes_with_the_width(monkeypatch) -> None:
    lay = layout()
    before = kernel._inputs_key(lay)
    assert kernel._inputs_key(lay) == before
    monkeypatch.setattr(kernel, "WIDTH", 8 if kernel.WIDTH != 8 else 4)
    assert kernel._inputs_key(lay) != before
