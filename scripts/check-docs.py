#!/usr/bin/env python3
"""Checks that every path, command and link the docs name exists.

    python3 scripts/check-docs.py       exit 0, or 1 listing every problem (FILE:LINE: what)

What it reads: README.md and every docs/src/**/*.md (the book), and the Markdown files those
pages {{#include}} (checked relative to themselves, as docs/md-include.py puts them into the book).
What it checks:

  links     every relative Markdown link and image target exists (#anchors stripped); a link
            to a .md page (or a bare #anchor) with an anchor needs a heading of that slug
            there (mdBook's and GitHub's rule: lowercase, spaces to '-', punctuation but '-'
            and '_' dropped; a repeated heading gets -1, -2, ...); included text counts.
  paths     every repository path in inline code, and in code blocks every path that starts
            with a top-level folder of the repository, exists. A word counts as a path when it
            has a '/' and starts with a top-level entry of the repository or ends with .rs,
            .toml, .sh, .py, .md, .proto, .yml or .yaml. Allowed: what .gitignore ignores (run
            directories, target/, third_party/, .venv, the token files: made by the build or
            by you), globs (`*`) and `{a,b}` braces that match, and placeholders in capitals
            (RUN, DIR, SETTING) outside the repository's own folders; absolute paths and URLs
            are not repository paths.
  commands  every `jsae SUBCOMMAND` in code (inline or blocks, where `jsae` starts a command:
            after a path, `--bin jsae --`, environment assignments, a pipe or `&&`) is a
            variant of the clap Subcommand enum in cli/src/commands.rs (kebab-cased); every
            `target/{release,debug}/NAME` and `--bin NAME` is a binary of the workspace; every
            `-p CRATE` a workspace crate, with its `--example NAME`.
  includes  every {{#include PATH}} target exists; every committed results/*/report.md is
            included by a page of the book.
  summary   docs/src/SUMMARY.md lists every .md under docs/src (or a page it lists includes
            it), and every entry it lists exists.
  crate map scripts/crate-map.py --check passes (docs/src/architecture/crates.md and the
            README's crate table match `cargo metadata`).
  readme    README.md has at most 150 lines, and its quick start holds the test command
            .ci/run runs.

Standard library only; runs in well under a second.
"""

import fnmatch
import glob
import importlib.util
import os
import re
import subprocess
import sys
import urllib.parse

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS_SRC = os.path.join(ROOT, "docs", "src")
KNOWN_EXT = (".rs", ".toml", ".sh", ".py", ".md", ".proto", ".yml", ".yaml")
README_MAX_LINES = 150
# Paths the docs tell the reader to create (not made by a build, and not git-ignored).
TO_BE_CREATED = {
    "deploy/docker-compose.tls.yml",  # deploy/README.md, "TLS and mutual TLS": you write it
}

problems = []
counts = {
    "files": 0,
    "links": 0,
    "anchors": 0,
    "paths": 0,
    "subcommands": 0,
    "binaries": 0,
    "crates": 0,
    "includes": 0,
    "summary": 0,
    "reports": 0,
}


def rel(path):
    return os.path.relpath(path, ROOT)


def problem(path, line, what):
    problems.append(f"{rel(path)}:{line}: {what}")


def read(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


# ---------------------------------------------------------------- the repository's facts


def top_level():
    return {e for e in os.listdir(ROOT) if e not in (".git",)}


def gitignore_patterns():
    pats = []
    path = os.path.join(ROOT, ".gitignore")
    if os.path.exists(path):
        for line in read(path).splitlines():
            line = line.strip()
            if line and not line.startswith("#") and not line.startswith("!"):
                pats.append(line)
    return pats


IGNORED = gitignore_patterns()


def ignored(path):
    """Whether .gitignore ignores this repository path (or a folder above it)."""
    path = path.strip("/")
    parts = path.split("/")
    for pat in IGNORED:
        anchored = pat.startswith("/") or "/" in pat.rstrip("/")
        p = pat.strip("/")
        if anchored:
            for i in range(1, len(parts) + 1):
                if fnmatch.fnmatchcase("/".join(parts[:i]), p):
                    return True
        elif any(fnmatch.fnmatchcase(part, p) for part in parts):
            return True
    return False


def subcommands():
    """Kebab-cased variants of the clap Subcommand enum in cli/src/commands.rs."""
    path = os.path.join(ROOT, "cli", "src", "commands.rs")
    text = read(path)
    m = re.search(r"#\[derive\([^)]*Subcommand[^)]*\)\]\s*pub enum \w+ \{", text)
    if not m:
        problem(path, 1, "no `#[derive(Subcommand)] pub enum` found to take the subcommands from")
        return set()
    names, depth, pending = set(), 1, None
    for line in text[m.end() :].splitlines():
        if depth == 1:
            rename = re.search(r'#\[command\([^)]*\bname\s*=\s*"([^"]+)"', line)
            if rename:
                pending = rename.group(1)
            v = re.match(r"    ([A-Z][A-Za-z0-9]*)\s*(?:[({,]|$)", line)
            if v:
                kebab = re.sub(r"(?<!^)(?=[A-Z])", "-", v.group(1)).lower()
                names.add(pending or kebab)
                pending = None
        depth += line.count("{") - line.count("}")
        if depth <= 0:
            break
    return names


def locked_packages():
    """The names of every package in Cargo.lock (a dependency named with `-p` is real too)."""
    if not hasattr(locked_packages, "names"):
        with open(os.path.join(ROOT, "Cargo.lock")) as f:
            locked_packages.names = set(re.findall(r'^name = "([^"]+)"', f.read(), re.M))
    return locked_packages.names


def load_crate_map():
    """scripts/crate-map.py as a module (its name has a hyphen): the one reader of `cargo metadata`."""
    spec = importlib.util.spec_from_file_location(
        "crate_map", os.path.join(ROOT, "scripts", "crate-map.py")
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def metadata():
    meta = load_crate_map().metadata()
    members = set(meta["workspace_members"])
    crates = {}
    for p in meta["packages"]:
        if p["id"] in members:
            crates[p["name"]] = {
                "bins": {t["name"] for t in p["targets"] if "bin" in t["kind"]},
                "examples": {t["name"] for t in p["targets"] if "example" in t["kind"]},
            }
    return crates


# ---------------------------------------------------------------- Markdown, roughly

FENCE = re.compile(r"^\s*(```+|~~~+)\s*([\w+-]*)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
INCLUDE = re.compile(r"\{\{#include\s+([^}\s]+)\s*\}\}")
CODE_SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.S)
LINK = re.compile(r"!?\[((?:[^\[\]]|\[[^\]]*\])*)\]\(\s*<?([^)\s>]*)>?(?:\s+\"[^\"]*\")?\s*\)")
REF_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s.*)?$")


def split_blocks(text):
    """Yields ('prose', start_line, text) and ('code', start_line, lang, text) blocks."""
    lines = text.split("\n")
    i, prose, prose_start = 0, [], 1
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m:
            if prose:
                yield ("prose", prose_start, "\n".join(prose))
                prose = []
            marker, lang, start = m.group(1), m.group(2), i + 1
            body = []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith(marker):
                body.append(lines[i])
                i += 1
            yield ("code", start + 1, lang, "\n".join(body))
            i += 1
            prose_start = i + 1
            continue
        if not prose:
            prose_start = i + 1
        prose.append(lines[i])
        i += 1
    if prose:
        yield ("prose", prose_start, "\n".join(prose))


def include_target(arg):
    """The file of an {{#include}} argument (a `:range` or `:anchor` suffix left off)."""
    m = re.match(r"(.+?\.[A-Za-z0-9]+)(?::.*)?$", arg)
    return m.group(1) if m else arg


def expanded(path, depth=0):
    """The text with {{#include}}s of Markdown files put in (for the headings it holds)."""
    text = read(path)
    if depth > 8:
        return text

    def put(m):
        target = os.path.normpath(os.path.join(os.path.dirname(path), include_target(m.group(1))))
        if target.endswith(".md") and os.path.isfile(target):
            return expanded(target, depth + 1)
        return ""

    return INCLUDE.sub(put, text)


def heading_text(raw):
    raw = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", raw)
    raw = raw.replace("`", "")
    return raw


def slug(text):
    out = []
    for c in heading_text(text).strip().lower():
        if c.isalnum() or c in "-_":
            out.append(c)
        elif c.isspace():
            out.append("-")
    return "".join(out)


_anchor_cache = {}


def anchors(path):
    if path not in _anchor_cache:
        ids, seen = set(), {}
        for block in split_blocks(expanded(path)):
            if block[0] != "prose":
                continue
            for line in block[2].split("\n"):
                m = HEADING.match(line)
                if m:
                    base = slug(m.group(2))
                    n = seen.get(base, 0)
                    ids.add(base if n == 0 else f"{base}-{n}")
                    seen[base] = n + 1
        _anchor_cache[path] = ids
    return _anchor_cache[path]


# ---------------------------------------------------------------- the checks


def check_link(path, line, target):
    if not target or re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target):
        return
    counts["links"] += 1
    target, _, anchor = target.partition("#")
    target = urllib.parse.unquote(target)
    if target:
        dest = os.path.normpath(os.path.join(os.path.dirname(path), target))
        if not os.path.exists(dest):
            problem(path, line, f"link target `{target}` does not exist")
            return
    else:
        dest = path
    if anchor and dest.endswith(".md") and os.path.isfile(dest):
        counts["anchors"] += 1
        if anchor not in anchors(dest):
            problem(path, line, f"no heading `#{anchor}` in {rel(dest)}")


def expand_braces(word):
    m = re.search(r"\{([^{}]*,[^{}]*)\}", word)
    if not m:
        return [word]
    out = []
    for alt in m.group(1).split(","):
        out += expand_braces(word[: m.start()] + alt + word[m.end() :])
    return out


PLACEHOLDER = re.compile(r"[A-Z]{2,}|^[A-Z]$")


def clean_word(word):
    word = word.replace("\\|", "|")
    word = word.strip("([<\"'`").rstrip(")]>\"'`,;.")
    if "=" in word and "://" not in word:
        word = word.rsplit("=", 1)[1]
    if word.startswith("$PWD/"):
        word = word[5:]
    if ":" in word and "://" not in word:
        word = word.split(":", 1)[0]
    while word.startswith("./"):
        word = word[2:]
    return word.rstrip(".,;")


def path_exists(word, bases):
    """Whether the path exists, is generated (ignored) or is a placeholder pattern."""
    for alt in expand_braces(word):
        alt = alt.rstrip("/")
        if ignored(alt) or alt in TO_BE_CREATED:
            continue
        if any(os.path.exists(os.path.join(b, alt)) for b in bases):
            continue
        parts = alt.split("/")
        has_placeholder = any(PLACEHOLDER.search(p) for p in parts)
        pattern = "/".join("*" if PLACEHOLDER.search(p) else p for p in parts)
        if ("*" in pattern) and any(glob.glob(os.path.join(b, pattern)) for b in bases):
            continue
        if has_placeholder and (parts[0] not in TOP or PLACEHOLDER.search(parts[0])):
            continue  # a path inside something made at run time (RUN/, DIR/, STORE/)
        return False
    return True


def check_path_word(path, line, word, bases, code_block):
    word = clean_word(word)
    if not word or "/" not in word or "://" in word or "..." in word:
        return
    if word[0] in "/~$-" or word.startswith("../"):
        return
    first = word.split("/", 1)[0]
    looks = first in TOP or (not code_block and word.rstrip("/").endswith(KNOWN_EXT))
    if not looks:
        return
    counts["paths"] += 1
    if not path_exists(word, bases):
        problem(path, line, f"path `{word}` does not exist")


COMMAND_START = re.compile(
    r"(?:^|[|;&(]\s*|\$\(\s*)(?:\$\s+)?(?:[A-Za-z_][A-Za-z0-9_]*=\S*\s+)*(?:(?:sudo|time|exec|nice(?:\s+-n\s*\d+)?)\s+)*$"
)


def check_commands(path, line, text):
    text = re.sub(r"\\\n\s*", " ", text)
    for offset, row in enumerate(text.split("\n")):
        row = row.replace("\\|", "|")
        for m in re.finditer(r"(?<![\w.-])jsae(?=\s)", row):
            before = row[: m.start()]
            if not (before.endswith("/") or before.endswith("--bin ") or COMMAND_START.search(before)):
                continue
            words = row[m.end() :].split()
            if words and words[0] == "--":
                words = words[1:]
            while words and words[0].startswith("--log-format"):
                words = words[1:] if "=" in words[0] else words[2:]
            if not words or not re.fullmatch(r"[a-z][a-z0-9-]*(\|[a-z][a-z0-9-]*)*", words[0]):
                continue
            for name in words[0].split("|"):
                counts["subcommands"] += 1
                if name not in SUBCOMMANDS:
                    problem(path, line + offset, f"`jsae {name}`: no such subcommand in cli/src/commands.rs")
        for m in re.finditer(r"target/(?:release|debug)/([A-Za-z0-9_-]+)", row):
            counts["binaries"] += 1
            if m.group(1) not in BINARIES:
                problem(path, line + offset, f"`{m.group(0)}`: no binary `{m.group(1)}` in the workspace")
        for m in re.finditer(r"--bin\s+([A-Za-z0-9_-]+)", row):
            counts["binaries"] += 1
            if m.group(1) not in BINARIES:
                problem(path, line + offset, f"`--bin {m.group(1)}`: no such binary in the workspace")
        for m in re.finditer(r"(?:^|\s)-p\s+([A-Za-z0-9_-]+)", row if "cargo " in row else ""):
            crate = m.group(1)
            counts["crates"] += 1
            if crate not in CRATES and crate not in locked_packages():
                problem(path, line + offset, f"`-p {crate}`: no such crate in the workspace or Cargo.lock")
                continue
            ex = re.search(r"--example\s+([A-Za-z0-9_-]+)", row[m.end() :])
            if ex and ex.group(1) not in CRATES[crate]["examples"]:
                problem(path, line + offset, f"`--example {ex.group(1)}`: not an example of {crate}")


def line_of(text, start_line, index):
    return start_line + text.count("\n", 0, index)


def check_file(path, included=False):
    counts["files"] += 1
    text = read(path)
    bases = [ROOT] + ([os.path.dirname(path)] if included else [])
    for block in split_blocks(text):
        if block[0] == "code":
            _, start, lang, body = block
            check_commands(path, start, body)
            if lang in ("sh", "bash", "shell", "console", "toml", "yaml", "yml"):
                for i, row in enumerate(body.split("\n")):
                    for word in row.split():
                        check_path_word(path, start + i, word, bases, code_block=True)
            continue
        _, start, body = block
        for m in CODE_SPAN.finditer(body):
            line = line_of(body, start, m.start())
            span = m.group(2)
            check_commands(path, line, span.replace("\n", " "))
            for word in span.split():
                check_path_word(path, line, word, bases, code_block=False)
        prose = CODE_SPAN.sub(lambda m: " " * len(m.group(0)), body)
        for m in LINK.finditer(prose):
            check_link(path, line_of(prose, start, m.start()), m.group(2))
        for i, row in enumerate(prose.split("\n")):
            d = REF_DEF.match(row)
            if d:
                check_link(path, start + i, d.group(1))
        for m in INCLUDE.finditer(prose):
            counts["includes"] += 1
            line = line_of(prose, start, m.start())
            target = os.path.normpath(os.path.join(os.path.dirname(path), include_target(m.group(1))))
            if not os.path.isfile(target):
                problem(path, line, f"{{{{#include {m.group(1)}}}}}: `{rel(target)}` does not exist")
                continue
            INCLUDED.setdefault(target, set()).add(path)
            if target.endswith(".md") and not target.startswith(DOCS_SRC + os.sep):
                if target not in CHECKED_INCLUDES:
                    CHECKED_INCLUDES.add(target)
                    check_file(target, included=True)


def check_summary(pages):
    summary = os.path.join(DOCS_SRC, "SUMMARY.md")
    if not os.path.isfile(summary):
        problem(summary, 1, "missing")
        return
    listed = set()
    for i, row in enumerate(read(summary).split("\n"), 1):
        for m in re.finditer(r"\[[^\]]*\]\(([^)]*)\)", row):
            counts["summary"] += 1
            target = m.group(1).strip()
            if not target:
                problem(summary, i, "a draft chapter (an entry without a file)")
                continue
            dest = os.path.normpath(os.path.join(DOCS_SRC, target))
            if not os.path.isfile(dest):
                problem(summary, i, f"entry `{target}` does not exist")
            listed.add(dest)
    for page in pages:
        if page == summary or page in listed:
            continue
        if any(p in listed for p in INCLUDED.get(page, ())):
            continue
        problem(page, 1, "not in SUMMARY.md (and not included by a page that is)")


def check_reports():
    for report in sorted(glob.glob(os.path.join(ROOT, "results", "*", "report.md"))):
        counts["reports"] += 1
        pages = [p for p in INCLUDED.get(report, ()) if p.startswith(DOCS_SRC + os.sep)]
        if not pages:
            problem(report, 1, "committed report not included by any page of docs/src")


def check_readme():
    readme = os.path.join(ROOT, "README.md")
    n = read(readme).count("\n")
    if n > README_MAX_LINES:
        problem(readme, n, f"{n} lines, more than {README_MAX_LINES}")
    ci = os.path.join(ROOT, ".ci", "run")
    if os.path.isfile(ci):
        tests = [l.strip() for l in read(ci).splitlines() if l.strip().startswith("cargo test")]
        blocks = [b[3] for b in split_blocks(read(readme)) if b[0] == "code"]
        for t in tests:
            if not any(t in b.split("\n") for b in blocks):
                problem(readme, 1, f"the quick start lacks .ci/run's test command `{t}`")


def check_crate_map():
    r = subprocess.run(
        [sys.executable, os.path.join(ROOT, "scripts", "crate-map.py"), "--check"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    if r.returncode != 0:
        problems.append("scripts/crate-map.py --check failed:\n" + r.stdout.rstrip())


TOP = top_level()
SUBCOMMANDS = subcommands()
CRATES = metadata()
BINARIES = {b for c in CRATES.values() for b in c["bins"]}
INCLUDED = {}
CHECKED_INCLUDES = set()


def main():
    pages = sorted(glob.glob(os.path.join(DOCS_SRC, "**", "*.md"), recursive=True))
    for path in [os.path.join(ROOT, "README.md")] + pages:
        check_file(path)
    check_summary(pages)
    check_reports()
    check_readme()
    check_crate_map()
    print(
        f"check-docs: {counts['files']} files (README.md, {len(pages)} pages under docs/src, "
        f"{len(CHECKED_INCLUDES)} included from elsewhere): {counts['links']} links "
        f"({counts['anchors']} with anchors), {counts['paths']} paths, "
        f"{counts['subcommands']} jsae subcommands ({len(SUBCOMMANDS)} known), "
        f"{counts['binaries']} binaries, {counts['crates']} crates named with -p, "
        f"{counts['includes']} includes, {counts['summary']} SUMMARY entries, "
        f"{counts['reports']} committed reports, the crate map"
    )
    if problems:
        for p in problems:
            print(p)
        print(f"check-docs: {len(problems)} problem(s)")
        return 1
    print("check-docs: OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
