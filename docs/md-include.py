#!/usr/bin/env python3
"""mdBook preprocessor: {{#include FILE.md}} with the included file's relative links kept.

mdBook's own `links` preprocessor pastes an included file as it is, so a relative link or
image in it (a report's `figures/x.svg`) would resolve against the including page instead.
This one runs before `links` (book.toml), puts in every whole-file include of a Markdown file
(no `:lines` or `:anchor` suffix) itself, rewriting the relative link and image targets of
the included text to point at the same files from the including page, and leaves every other
include to mdBook. Standard library only; mdBook runs it from the book's folder (docs/).
"""

import json
import os
import re
import sys

INCLUDE = re.compile(r"\{\{#include\s+([^}\s:]+\.md)\s*\}\}")
LINK = re.compile(r"(!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?)([^)\s>]+)")
FENCE = re.compile(r"^\s*(```+|~~~+)")


def rebase(text, from_dir, to_dir):
    """Relative link targets in `text` (written from from_dir) rewritten for to_dir."""

    def fix(m):
        target = m.group(2)
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith(("#", "/")):
            return m.group(0)
        path, hash_, anchor = target.partition("#")
        new = os.path.relpath(os.path.normpath(os.path.join(from_dir, path)), to_dir)
        return m.group(1) + new.replace(os.sep, "/") + hash_ + anchor

    out, fence = [], None
    for line in text.split("\n"):
        f = FENCE.match(line)
        if f and (fence is None or f.group(1).startswith(fence)):
            fence = None if fence else f.group(1)[:3]
        out.append(line if fence or f else LINK.sub(fix, line))
    return "\n".join(out)


def expand(text, file_dir, page_dir, depth=0):
    if depth > 8:
        return text

    def put(m):
        path = os.path.normpath(os.path.join(file_dir, m.group(1)))
        if not os.path.isfile(path):
            return m.group(0)  # mdBook reports it
        with open(path, encoding="utf-8") as f:
            inner = f.read()
        inner = expand(inner, os.path.dirname(path), page_dir, depth + 1)
        return rebase(inner, os.path.dirname(path), page_dir)

    return INCLUDE.sub(put, text)


def walk(node, src):
    if isinstance(node, dict):
        chapter = node.get("Chapter")
        if isinstance(chapter, dict) and chapter.get("path") and chapter.get("content"):
            page_dir = os.path.dirname(os.path.join(src, chapter["path"]))
            chapter["content"] = expand(chapter["content"], page_dir, page_dir)
        for value in node.values():
            walk(value, src)
    elif isinstance(node, list):
        for value in node:
            walk(value, src)


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "supports":
        return 0
    context, book = json.load(sys.stdin)
    src = os.path.join(context["root"], context["config"]["book"].get("src", "src"))
    walk(book, src)
    json.dump(book, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
