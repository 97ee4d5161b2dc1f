#!/usr/bin/env python3
"""Checks the documentation's links: every relative link and every #anchor resolves.

    scripts/check-docs.py [ROOT]        check the repository (default: this script's ../)
    scripts/check-docs.py --self-test   check the checker on a tiny book with known faults
    scripts/check-docs.py --tour RIG [--after-demo] [ROOT]
                                            run the README's tour with the rig binary RIG (below)

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

--tour RIG runs the console block of README.md's "A five-minute tour" as a new user would, with
RIG's folder first on PATH, in a new temp folder holding a copy of plans/ and models/ (the files
the tour names): each `$ command` must exit 0 and print its key output lines, the lines shown
under it, in order (a `...` line skips any number of lines; decimals such as timings and fitted
values match any decimal, every other character must be equal). `command &` starts a background
job (its lines must appear while it runs; the next step waits up to 60 s for the first), and
`kill %N` stops the Nth background job with SIGTERM and checks it exits 0 with its lines.
With --after-demo, scripts/demo.sh runs first with the same binary (RIG_DEMO_BIN) into the
temp folder's datasets/, as a new user runs the demo and then the tour: the tour must not
trip over what the demo left.
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


TOUR_HEADING = "## A five-minute tour on the simulated rig"
DECIMAL = re.compile(r"-?\d+\.\d+")


def tour_steps(readme_text):
    """The README tour's console block as [(line_no, command, [expected lines])]."""
    lines = readme_text.splitlines()
    try:
        start = lines.index(TOUR_HEADING)
    except ValueError:
        raise SystemExit(f"check-docs --tour: README.md has no {TOUR_HEADING!r} section")
    i = start
    while i < len(lines) and lines[i].strip() != "```console":
        i += 1
    steps = []
    for j in range(i + 1, len(lines)):
        line = lines[j]
        if line.strip() == "```":
            break
        if line.startswith("$ "):
            command = re.sub(r"\s+#.*$", "", line[2:]).strip()
            steps.append((j + 1, command, []))
        elif line.strip() and steps:
            steps[-1][2].append(line)
    if not steps:
        raise SystemExit("check-docs --tour: the tour has no `$ command` lines")
    return steps


def line_pattern(expected):
    """A regex for one expected output line: decimals match any decimal, the rest literally."""
    parts, last = [], 0
    for m in DECIMAL.finditer(expected):
        parts.append(re.escape(expected[last:m.start()]))
        parts.append(r"-?\d+\.\d+")
        last = m.end()
    parts.append(re.escape(expected[last:]))
    return re.compile("^" + "".join(parts) + "$")


def missing_lines(expected, output):
    """The expected lines not found in `output`, in order ('...' skips any lines)."""
    got = [l.rstrip() for l in output.splitlines()]
    at = 0
    for k, want in enumerate(expected):
        if want.strip() == "...":
            continue
        pattern = line_pattern(want.rstrip())
        while at < len(got) and not pattern.match(got[at]):
            at += 1
        if at == len(got):
            return expected[k:]
        at += 1
    return []


def run_tour(root, rig_bin, after_demo=False):
    import shutil
    import signal
    import subprocess
    import time

    rig_bin = os.path.abspath(rig_bin)
    if not os.access(rig_bin, os.X_OK):
        print(f"check-docs --tour: {rig_bin} is not an executable rig binary", file=sys.stderr)
        return 1
    with open(os.path.join(root, "README.md"), encoding="utf-8") as f:
        steps = tour_steps(f.read())
    failures = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="rig-tour-") as work:
        for folder in ("plans", "models"):
            shutil.copytree(os.path.join(root, folder), os.path.join(work, folder))
        env = dict(os.environ)
        env["PATH"] = os.path.dirname(rig_bin) + os.pathsep + env.get("PATH", "")
        for var in ("RIG_CONFIG", "RIG_DAEMON_TOKEN"):
            env.pop(var, None)
        background = []  # (line_no, command, Popen, log path, expected)
        if after_demo:
            demo_env = dict(env, RIG_DEMO_BIN=rig_bin, RIG_DEMO_OUT=os.path.join(work, "datasets"))
            demo = subprocess.run([os.path.join(root, "scripts", "demo.sh")], env=demo_env, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, errors="replace")
            print(f"tour: scripts/demo.sh {'ok' if demo.returncode == 0 else 'FAILED'} ({time.monotonic() - t0:.0f} s)")
            if demo.returncode != 0:
                print(f"check-docs --tour: scripts/demo.sh exited {demo.returncode}:\n{demo.stdout}", file=sys.stderr)
                return 1

        def log_of(job):
            with open(job[3], encoding="utf-8", errors="replace") as f:
                return f.read()

        for line_no, command, expected in steps:
            where = f"README.md:{line_no}: $ {command}"
            kill = re.fullmatch(r"kill %(\d+)", command)
            if kill:
                n = int(kill.group(1))
                if not 1 <= n <= len(background) or background[n - 1] is None:
                    failures.append(f"{where}: no background job %{n}")
                    continue
                job = background[n - 1]
                background[n - 1] = None
                job[2].send_signal(signal.SIGTERM)
                try:
                    rc = job[2].wait(timeout=30)
                except subprocess.TimeoutExpired:
                    job[2].kill()
                    rc = job[2].wait()
                    failures.append(f"{where}: the job did not end within 30 s of SIGTERM")
                try:
                    os.killpg(job[2].pid, signal.SIGKILL)  # anything it left behind
                except ProcessLookupError:
                    pass
                out = log_of(job)
                if rc != 0:
                    failures.append(f"{where}: `{job[1]}` exited {rc}:\n{out}")
                lost = missing_lines(job[4] + expected, out)
                if lost:
                    failures.append(f"{where}: `{job[1]}` did not print {lost[0]!r}; it printed:\n{out}")
                print(f"tour: {where} ok ({time.monotonic() - t0:.0f} s)")
                continue
            if command.endswith("&"):
                log = os.path.join(work, f".tour-job-{len(background) + 1}.log")
                # `exec`: the signal of `kill %N` goes to the command, not to a shell around it.
                proc = subprocess.Popen("exec " + command[:-1].strip(), shell=True, cwd=work, env=env,
                                        stdout=open(log, "w"), stderr=subprocess.STDOUT,
                                        start_new_session=True)
                job = (line_no, command[:-1].strip(), proc, log, expected)
                background.append(job)
                # The next step needs it up: wait for its first line.
                first = [l for l in expected if l.strip() != "..."][:1]
                deadline = time.monotonic() + 60
                while first and missing_lines(first, log_of(job)) and proc.poll() is None and time.monotonic() < deadline:
                    time.sleep(0.2)
                if first and missing_lines(first, log_of(job)):
                    failures.append(f"{where}: did not print {first[0]!r} within 60 s; it printed:\n{log_of(job)}")
                print(f"tour: {where} started ({time.monotonic() - t0:.0f} s)")
                continue
            done = subprocess.run(command, shell=True, cwd=work, env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, errors="replace")
            if done.returncode != 0:
                failures.append(f"{where}: exited {done.returncode}:\n{done.stdout}")
            else:
                lost = missing_lines(expected, done.stdout)
                if lost:
                    failures.append(f"{where}: did not print {lost[0]!r}; it printed:\n{done.stdout}")
            print(f"tour: {where} {'ok' if done.returncode == 0 else 'FAILED'} ({time.monotonic() - t0:.0f} s)")
        for job in background:
            if job is not None:
                failures.append(f"README.md:{job[0]}: background job `{job[1]}` was never stopped by the tour")
                try:
                    os.killpg(job[2].pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                job[2].wait()
    for f in failures:
        print(f"check-docs --tour: {f}", file=sys.stderr)
    if failures:
        print(f"check-docs --tour: {len(failures)} step(s) of the README tour failed", file=sys.stderr)
        return 1
    print(f"check-docs --tour: the README tour ran as written ({len(steps)} steps, {time.monotonic() - t0:.0f} s)")
    return 0


def main(argv):
    if argv[1:2] == ["--self-test"]:
        return self_test()
    if argv[1:2] == ["--tour"]:
        rest = argv[2:]
        after_demo = "--after-demo" in rest
        rest = [a for a in rest if a != "--after-demo"]
        if len(rest) not in (1, 2):
            print("usage: scripts/check-docs.py --tour PATH/TO/rig [--after-demo] [ROOT]", file=sys.stderr)
            return 2
        root = rest[1] if len(rest) == 2 else os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
        return run_tour(root, rest[0], after_demo)
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
