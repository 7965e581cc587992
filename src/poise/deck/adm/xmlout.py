"""A translated Adams dataset as MotionSolve XML text (``poise convert``).

The XML holds exactly the element records the reader built (the same attribute text the XML
builder typed), so reading it back gives the same model and results. The dataset's title and
comments come along as XML comments before the elements they preceded, each element after a
short note of the statement and line it came from; labels are ``label`` attributes. Elements a
command file deactivated before any analysis are left out with a comment saying so.
"""
from __future__ import annotations

import os
import re

_ATTR_ESC = str.maketrans({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;",
                           "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"})
_TEXT_ESC = str.maketrans({"&": "&amp;", "<": "&lt;", ">": "&gt;"})
_CTRL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def _comment(text: str) -> str:
    """Text safe inside ``<!-- -->`` (no ``--``, no trailing ``-``, no control characters)."""
    t = _CTRL.sub("?", text)
    t = re.sub(r"-{2,}", lambda m: "=" * len(m.group(0)), t)
    if t.endswith("-"):
        t += " "
    return t


def _element(r, indent: str) -> list[str]:
    attrs = " ".join(f'{k}="{_CTRL.sub("?", str(v)).translate(_ATTR_ESC)}"'
                     for k, v in r.attrs.items())
    head = f"{indent}<{r.tag}" + (f" {attrs}" if attrs else "")
    if r.text is None:
        return [head + "/>"]
    body = _CTRL.sub("?", r.text).translate(_TEXT_ESC)
    lines = body.split("\n")
    if len(lines) == 1:
        return [f"{head}>{body}</{r.tag}>"]
    return [head + ">", *(f"{indent}  {ln}" for ln in lines), f"{indent}</{r.tag}>"]


def to_xml(ctx, source: str) -> str:
    """The XML deck text of a translation context (records in dataset, then command order)."""
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f"<!-- {_comment('written by poise convert from ' + os.path.basename(source))} -->"]
    title = getattr(ctx, "title", "")
    if title:
        out.append(f"<!-- {_comment('title: ' + title)} -->")
    out.append("<MotionSolve>")
    for section, tag in (("model", "Model"), ("command", "Command")):
        out.append(f"  <{tag}>")
        last = None
        for r in ctx.recs:
            if r.section != section:
                continue
            for c in r.comments:
                out.append(f"    <!-- {_comment(c)} -->")
            src = (os.path.basename(r.file), r.line, r.who)
            if src != last:
                note = f"{r.who}, {src[0]} line {r.line}"
                if r.removed:
                    note += ": deactivated by the command file before any analysis, left out"
                out.append(f"    <!-- {_comment(note)} -->")
                last = src
            if not r.removed:
                out.extend(_element(r, "    "))
        if section == "model":
            out.extend(f"    <!-- {_comment(c)} -->" for c in getattr(ctx, "trailing", ()))
        out.append(f"  </{tag}>")
    out.append("</MotionSolve>")
    return "\n".join(out) + "\n"
