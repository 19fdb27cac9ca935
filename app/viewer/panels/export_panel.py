"""The export dialog: format (PLY, compressed PLY as SuperSplat reads it, .splat, SPZ, glTF .glb), the SH bands kept,
the whole model or the selection, and the file's size before it is written (SPZ: once compressed;
training/model/export.py does the writing)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from imgui_bundle import imgui

from app.viewer.edit.colour_view import export_baker
from app.viewer.live.runs import submit_to_trainer
from training.core.trainer import UseModel
from app.viewer.panels.text_colours import GREY
from training.model.formats import BY_NAME, NAMES


def model_to_export(doc):
    """The opened model after its edits, as shown (the view shows no trainer's model)."""
    if doc.editor is not None:
        return doc.in_world(doc.edited_gaussians())  # scaled and levelled as shown (measure tools)
    raise ValueError("no model to export: open one or run a reconstruction")


def selection_mask(doc, count: int):
    """The editor's selection when it applies to the model being exported (same Gaussians), else None."""
    if doc.editor is None or len(doc.editor.selected) != count:
        return None
    return doc.editor.selected


def export_section(doc, session, ui) -> None:
    from training.model.export import export_size, human_size, max_sh_bands

    if doc.editor is None:
        return
    imgui.separator_text("Export")
    st = ui.export
    changed, i = imgui.combo("format", NAMES.index(st.format), list(NAMES))
    if changed:
        st.format = NAMES[i]
        st.path = str(Path(st.path).parent / ("export" + BY_NAME[st.format].suffix))
    top = max_sh_bands(st.format)
    if top > 0:
        _, st.sh_bands = imgui.slider_int("SH bands kept", min(st.sh_bands, top), 0, top)
    _, st.selection_only = imgui.checkbox("selection only", st.selection_only)
    if st.format == "ply":
        _, st.compact_sh = imgui.checkbox("only the kept bands' coefficients", st.compact_sh)
    if st.format == "spz":
        _, v = imgui.combo("SPZ version", 0 if st.spz_version == 4 else 1, ["4 (current)", "3 (older readers)"])
        st.spz_version = 4 if v == 0 else 3
    _, st.path = imgui.input_text("file", st.path)
    count = _count(doc, session, st.selection_only)
    if count is not None:
        bands = 0 if top == 0 else min(st.sh_bands, top)
        size = export_size(st.format, bands, count, pad_sh=not st.compact_sh)
        imgui.text(f"{count:,} Gaussians, " + ("size known once compressed" if size is None else human_size(size)))
    else:
        imgui.text_colored(GREY, "nothing to export")
    if imgui.button("Export"):
        ui.messages.guarded("export", write, doc, session, ui)


def _count(doc, session, selection_only: bool) -> int | None:
    snap = session.snapshot() if session.has_trainer else doc.model
    if snap is None:
        return None
    n = len(snap)
    if selection_only:
        mask = selection_mask(doc, n)
        return None if mask is None else int(mask.sum())
    return n


def write(doc, session, ui) -> None:
    """Export the model on screen. A running trainer's model is copied and written on the training thread between
    two steps (a consistent model, never one half-way through a step or an edit); the line comes back later. An
    ended run's is written at once."""
    from training.model.export import human_size, write_export

    st = replace(ui.export)  # the settings as they are now: the write may run later, on the training thread
    bake = export_baker(doc, session)  # the colour edits as shown now
    selection = doc.editor.selected.copy() if doc.editor is not None else None
    path = Path(st.path)
    path.parent.mkdir(parents=True, exist_ok=True)

    def export(g):
        mask = None
        if st.selection_only:
            mask = selection if selection is not None and len(selection) == len(g) else None
            if mask is None:
                raise ValueError("no selection on this model")
        top_bands = 0 if st.format == "splat" else st.sh_bands
        return write_export(path, g, fmt=st.format, sh_bands=min(top_bands, g.sh_degree), mask=mask,
                            pad_sh=not st.compact_sh, spz_version=st.spz_version)

    def said(result) -> None:
        ui.messages.say(f"wrote {result.path} ({result.count:,} Gaussians, {human_size(result.size)})")
        ui.export.written.append(result.path)

    if session.has_trainer:
        command = UseModel(lambda g, original_sh: export(bake(g, True, original_sh)))
        if session.running:
            submit_to_trainer(session, ui, "export", command, said)
        else:
            said(session.submit(command).result())  # an ended run: answered at once
    else:
        said(export(bake(model_to_export(doc))))
