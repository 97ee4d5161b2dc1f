#!/usr/bin/env python3
"""Checks the documentation's links: every relative link and every #anchor resolves.

    scripts/check-docs.py [ROOT]        check the repository (default: this script's ../)
    scripts/check-docs.py --self-test   check the checker on a tiny book with known faults

Files checked: README.md, CHANGELOG.md, TESTING.md and docs/src/**/*.md. For each link,
image and link reference definition (and <a href>/<img src> in raw HTML):

- http(s)://, mailto: and other URLs with a scheme are not fetched;
- a relative path must name a file or folder that exists (paths into the repository, such as
  ../../tools/eval_default.sh from a chapter, are checked too);
- an #anchor must be the id of a heading of the target page (or of the same page): mdBook's
  rule for pages under docs/src, GitHub's for the others. Both lower-case the heading's text,
  keep letters, digits, '-' and '_', turn each whitespace character into '-' and drop the
  rest; a repeated id gets -1, -2, ... in order. Explicit ids ({#id}) and <a id|name="..">
  count too.

And for the book: every .md file under docs/src is listed in docs/src/SUMMARY.md, and every
SUMMARY entry exists.

Links in fenced or indented code blocks and in `code spans` are not links and are skipped.
Exits 1 with one `file:line: broken link ...` line per fault; 0 when every link resolves.
Python 3 standard library only.
"""

import os
import re
import sys
import tempfile
import unicodedata
from urllib.parse import unquote

ROOT_FILES = ["README.md", "CHANGELOG.md", "TESTING.md"]
BOOK_SRC = os.path.join("docs", "src")

FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
HEADING = re.compile(r"^ {0,3}(#{1,6})[ \t]+(.*?)[ \t]*#*[ \t]*$")
SETEXT = re.compile(r"^ {0,3}(=+|-+)[ \t]*$")
LIST_ITEM = re.compile(r"^ {0,3}([-+*]|\d{1,9}[.)])[ \t]")
CODE_SPAN = re.compile(r"(`+)(.+?)(?<!`)\1(?!`)", re.S)
# [text](target "title") and ![alt](target); target may be <...>; one level of nested [] in text.
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*(<[^>]*>|[^\s)]*)(?:\s+(?:\"[^\"]*\"|'[^']*'|\([^)]*\)))?\s*\)")
REF_DEF = re.compile(r"^ {0,3}\[([^\]]+)\]:\s*(<[^>]*>|\S+)")
HTML_ATTR = re.compile(r"<(?:a|img)\b[^>]*?\b(?:href|src)\s*=\s*[\"']([^\"']*)[\"']", re.I)
HTML_ID = re.compile(r"<[a-z][^>]*?\b(?:id|name)\s*=\s*[\"']([^\"']+)[\"']", re.I)
EXPLICIT_ID = re.compile(r"\s*\{#([^}\s]+)[^}]*\}\s*$")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def code_mask(lines):
    """For each line, whether it is inside a fenced or an indented code block."""
    mask = [False] * len(lines)
    fence = None
    prev_blank = True
    prev_text_kind = "blank"  # "blank", "text", "list", "code"
    in_list = False
    for i, line in enumerate(lines):
        if fence is not None:
            mask[i] = True
            stripped = line.strip()
            if stripped.startswith(fence[0] * len(fence)) and set(stripped) <= {fence[0]}:
                fence = None
            continue
        m = FENCE.match(line)
        if m:
            fence = m.group(1)
            mask[i] = True
            prev_blank = False
            prev_text_kind = "code"
            continue
        blank = line.strip() == ""
        indented = line.startswith("    ") or line.startswith("\t")
        if not blank and indented and (prev_text_kind == "code" or (prev_blank and not in_list)):
            mask[i] = True
            prev_text_kind = "code"
            prev_blank = False
            continue
        if blank:
            prev_blank = True
            if prev_text_kind != "code":
                prev_text_kind = "blank"
            continue
        if LIST_ITEM.match(line):
            in_list = True
        elif not indented and prev_blank:
            in_list = False
        prev_blank = False
        prev_text_kind = "text"
    return mask


def heading_text(raw):
    """The text a renderer would put in a heading: inline code kept, markup dropped."""
    text = EXPLICIT_ID.sub("", raw)
    parts = []
    pos = 0
    for m in CODE_SPAN.finditer(text):
        parts.append(strip_markup(text[pos:m.start()]))
        parts.append(m.group(2).strip() if m.group(2).strip() else m.group(2))
        pos = m.end()
    parts.append(strip_markup(text[pos:]))
    return "".join(parts)


def strip_markup(text):
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links and images: their text
    text = re.sub(r"<[^>]*>", "", text)  # raw HTML tags
    text = text.replace("*", "")  # emphasis
    text = re.sub(r"(^|\W)_+|_+(\W|$)", r"\1\2", text)  # _emphasis_ (not snake_case)
    return text


def slug(text):
    """mdBook's normalize_id (GitHub's is the same for what these pages hold)."""
    out = []
    for ch in text.strip():
        if ch.isalnum() or ch in "-_":
            out.append(ch.lower() if ch.isascii() else unicodedata.normalize("NFC", ch.lower()))
        elif ch.isspace():
            out.append("-")
    return "".join(out)


_ANCHORS = {}


def anchors_of(path):
    """Every id a page's headings and HTML elements define."""
    if path in _ANCHORS:
        return _ANCHORS[path]
    with open(path, encoding="utf-8") as f:
        lines = f.read().split("\n")
    mask = code_mask(lines)
    ids = set()
    counts = {}
    for i, line in enumerate(lines):
        if mask[i]:
            continue
        for m in HTML_ID.finditer(strip_code_spans(line)):
            ids.add(m.group(1))
        raw = None
        m = HEADING.match(line)
        if m:
            raw = m.group(2)
        elif i > 0 and SETEXT.match(line) and lines[i - 1].strip() and not mask[i - 1] \
                and not HEADING.match(lines[i - 1]) and not LIST_ITEM.match(lines[i - 1]) \
                and (line.strip()[0] == "=" or not lines[i - 1].lstrip().startswith("|")):
            raw = lines[i - 1].strip()
        if raw is None:
            continue
        explicit = EXPLICIT_ID.search(raw)
        if explicit:
            ids.add(explicit.group(1))
            continue
        base = slug(heading_text(raw))
        n = counts.get(base, 0)
        ids.add(base if n == 0 else f"{base}-{n}")
        counts[base] = n + 1
    _ANCHORS[path] = ids
    return ids


def strip_code_spans(line):
    return CODE_SPAN.sub(lambda m: " " * len(m.group(0)), line)


def links_of(path):
    """(line number, target) of every link on a page, outside code."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    lines = text.split("\n")
    mask = code_mask(lines)
    # Join the prose back with code blocks blanked, so a link wrapped over two lines is found,
    # and blank code spans (which may span lines) keeping the offsets.
    prose = "\n".join("" if mask[i] else line for i, line in enumerate(lines))
    prose = CODE_SPAN.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), prose)
    found = []

    def line_of(offset):
        return prose.count("\n", 0, offset) + 1

    for m in INLINE_LINK.finditer(prose):
        found.append((line_of(m.start()), m.group(1)))
    for m in HTML_ATTR.finditer(prose):
        found.append((line_of(m.start()), m.group(1)))
    for i, line in enumerate(prose.split("\n")):
        m = REF_DEF.match(line)
        if m and not line.lstrip().startswith("[^"):
            found.append((i + 1, m.group(2)))
    return found


def check_link(root, page, target):
    """None when the link resolves, else why not."""
    target = target.strip()
    if target.startswith("<") and target.endswith(">"):
        target = target[1:-1]
    if not target or SCHEME.match(target) or target.startswith("//"):
        return None
    path_part, _, anchor = target.partition("#")
    path_part = unquote(path_part.split("?")[0])
    if path_part.startswith("/"):
        return "absolute path (use a path relative to the page)"
    if path_part:
        dest = os.path.normpath(os.path.join(os.path.dirname(page), path_part))
        if not os.path.exists(dest):
            return f"{os.path.relpath(dest, root)} does not exist"
        if not os.path.realpath(dest).startswith(os.path.realpath(root) + os.sep) and \
                os.path.realpath(dest) != os.path.realpath(root):
            return "points outside the repository"
    else:
        dest = page
    if anchor:
        if os.path.isdir(dest) or not dest.endswith(".md"):
            return f"anchor #{anchor} on a file that is not a Markdown page"
        if unquote(anchor) not in anchors_of(dest):
            return f"no heading with id #{anchor} in {os.path.relpath(dest, root)}"
    return None


def book_pages(root):
    src = os.path.join(root, BOOK_SRC)
    pages = []
    for dirpath, dirnames, filenames in os.walk(src):
        dirnames.sort()
        for name in sorted(filenames):
            if name.endswith(".md"):
                pages.append(os.path.join(dirpath, name))
    return pages


def check_summary(root):
    """Every chapter under docs/src is listed in SUMMARY.md."""
    errors = []
    src = os.path.join(root, BOOK_SRC)
    summary = os.path.join(src, "SUMMARY.md")
    if not os.path.exists(summary):
        return [f"{os.path.relpath(summary, root)}:1: missing (the book's table of contents)"]
    listed = set()
    for line_no, target in links_of(summary):
        path_part = unquote(target.partition("#")[0])
        if not path_part or SCHEME.match(path_part):
            continue
        # An entry whose file is missing is reported as a broken link by check().
        listed.add(os.path.normpath(os.path.join(src, path_part)))
    for page in book_pages(root):
        if os.path.normpath(page) == os.path.normpath(summary):
            continue
        if os.path.normpath(page) not in listed:
            errors.append(f"{os.path.relpath(page, root)}:1: chapter not listed in "
                          f"{os.path.relpath(summary, root)} (mdBook would not render it)")
    return errors


def check(root):
    """Every fault found under root, as 'file:line: message' lines."""
    _ANCHORS.clear()
    root = os.path.abspath(root)
    pages = [os.path.join(root, f) for f in ROOT_FILES if os.path.exists(os.path.join(root, f))]
    pages += book_pages(root)
    errors = []
    for page in pages:
        for line_no, target in links_of(page):
            why = check_link(root, page, target)
            if why:
                errors.append(f"{os.path.relpath(page, root)}:{line_no}: broken link '{target}': {why}")
    errors += check_summary(root)
    return errors


def self_test():
    """Writes a tiny book with known faults and checks that exactly those are reported."""
    files = {
        "README.md": (
            "# Tiny\n"
            "\n"
            "See [the guide](docs/src/intro.md#a-heading-with-code-and-punctuation-yes) and\n"
            "[a missing page](docs/src/nope.md).\n"                       # line 4: broken file
            "## Same\n"
            "## Same\n"
            "Back to [the second](#same-1) and [a third](#same-2).\n"     # line 7: broken anchor
            "\n"
            "    [not a link](nowhere.md)\n"
            "\n"
            "```\n"
            "[not a link either](nowhere.md)\n"
            "```\n"
            "`[nor this](nowhere.md)` and [a file](scripts/tool.sh).\n"
        ),
        "scripts/tool.sh": "#!/bin/sh\n",
        "docs/src/SUMMARY.md": (
            "# Summary\n"
            "\n"
            "- [Intro](intro.md)\n"
            "- [Gone](gone.md)\n"                                           # line 4: missing chapter
        ),
        "docs/src/intro.md": (
            "# Intro\n"
            "\n"
            "## A heading with `code` and punctuation: (yes)!\n"
            "\n"
            "[Up](../../README.md#same), [a picture](images/a.png), [bad](#no-such-heading).\n"  # line 5
            "![missing picture](images/b.png)\n"                            # line 6
            "[repo file](../../scripts/tool.sh) [outside](../../../x.md)\n"  # line 7
        ),
        "docs/src/images/a.png": "",
        "docs/src/orphan.md": "# Not in the summary\n",                   # unlisted chapter
    }
    expected = {
        ("README.md", 4), ("README.md", 7),
        ("docs/src/SUMMARY.md", 4),
        ("docs/src/intro.md", 5), ("docs/src/intro.md", 6), ("docs/src/intro.md", 7),
        ("docs/src/orphan.md", 1),
    }
    with tempfile.TemporaryDirectory() as tmp:
        root = os.path.join(tmp, "repo")
        for name, body in files.items():
            path = os.path.join(root, name)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            with open(path, "w", encoding="utf-8") as f:
                f.write(body)
        errors = check(root)
    got = set()
    for e in errors:
        file, line, _ = e.split(":", 2)
        got.add((file, int(line)))
    if got != expected:
        for e in errors:
            print(f"  reported: {e}", file=sys.stderr)
        print(f"check-docs self-test FAILED: missed {sorted(expected - got)}, "
              f"wrongly reported {sorted(got - expected)}", file=sys.stderr)
        return 1
    print(f"check-docs self-test: ok ({len(errors)} planted faults reported, nothing else)")
    return 0


def main(argv):
    if argv[1:2] == ["--self-test"]:
        return self_test()
    root = argv[1] if len(argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    errors = check(root)
    for e in errors:
        print(e, file=sys.stderr)
    if errors:
        print(f"check-docs: {len(errors)} broken link(s) or chapter(s)", file=sys.stderr)
        return 1
    pages = len(book_pages(os.path.abspath(root))) + sum(os.path.exists(os.path.join(root, f)) for f in ROOT_FILES)
    print(f"check-docs: every relative link and anchor resolves ({pages} pages)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
