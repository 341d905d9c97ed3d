#!/usr/bin/env python3
"""Check the relative links and images of README.md and the user guide.

    python3 scripts/check_links.py              # README.md and every .md under docs/guide
    python3 scripts/check_links.py target/book  # the same, then every .html of the built book

Every relative link or image of the markdown must resolve to a file or directory that exists
in the repository; every relative link or image of the built book must resolve under the
book's own directory, so that the book still works copied or hosted elsewhere
(scripts/build_book.sh copies what the guide links outside docs/guide into the book, or turns
the link into a URL of the repository). CI checks a copy of the built book moved out of the
repository. A `#anchor` must name a
heading of the target markdown file (GitHub-style slug: lowercase, spaces to '-', punctuation
dropped except '-' and '_', a repeated heading gets -1, -2, ...) or an explicit id in it, or an
`id`/`name` of the target HTML file. mdBook's `{{#include FILE}}` and scripts/stage_book.py's `<!-- book-include: FILE -->` must
name an existing file.
Links with a scheme (http:, https:, mailto:, ...) are not checked. Links inside code spans and
fenced code blocks are not links.

With the built book it also checks what the pages show: no en dash directly before a
lowercase letter anywhere (`–release`: smart punctuation turned a flag's `--` into a dash, and
the flag no longer survives copy-paste), and no entity shown as typed (`&lt;name&gt;`) inside
code on the generated references (reference/cli.html, reference/config.html).

Exit status 0 when every link resolves and no page shows either, 1 otherwise, with one line
per problem: `FILE:LINE: TARGET: why`. Python 3 standard library only.
"""

import html.parser
import os
import re
import sys
import urllib.parse

ROOT = os.path.realpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")
FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
ATX = re.compile(r"^ {0,3}(#{1,6})(?:[ \t]+(.*?))?(?:[ \t]+#+)?[ \t]*$")
INCLUDE = re.compile(r"\{\{#(?:include|rustdoc_include|playground)\s+([^}\s]+)[^}]*\}\}")
# An inline link or image: [text](dest "title") / ![alt](<dest>). The text may hold one
# level of nested brackets ([`x`][y] style text is rare enough to leave out).
INLINE = re.compile(
    r"(!?)\[(?:[^\[\]\\]|\\.|\[[^\[\]]*\])*\]\(\s*(<[^>\n]*>|[^\s()]+(?:\([^\s()]*\)[^\s()]*)*)"
    r"(?:\s+(?:\"[^\"]*\"|'[^']*'|\([^)]*\)))?\s*\)"
)
# scripts/stage_book.py's book-only include: `<!-- book-include: PATH -->` on a line of its own.
BOOK_INCLUDE = re.compile(r"^<!--\s*book-include:\s*(\S+)\s*-->\s*$")
REFDEF = re.compile(r"^ {0,3}\[([^\]]+)\]:\s*(<[^>]*>|\S+)")
HTML_ATTR = re.compile(r"<(?:a|img)\b[^>]*?\b(?:href|src)\s*=\s*(\"[^\"]*\"|'[^']*')", re.I)
HTML_ID = re.compile(r"<[A-Za-z][^>]*?\b(?:id|name)\s*=\s*(\"[^\"]*\"|'[^']*')", re.I)
GITHUB_LINE = re.compile(r"^L\d+(?:C\d+)?(?:-L\d+(?:C\d+)?)?$")
# An en dash where a flag's "--" was: smart punctuation's work on `--release`.
DASHED_FLAG = re.compile("\u2013[a-z]")
# An HTML entity a page shows as text (the markdown escaped it where it was already literal).
SHOWN_ENTITY = re.compile(r"&(?:lt|gt|amp|quot);")
# The generated references, whose code spans must show `<name>`, not `&lt;name&gt;`.
REFERENCE_PAGES = (os.path.join("reference", "cli.html"), os.path.join("reference", "config.html"))


def rel(path):
    """A path as printed: relative to the repository when inside it."""
    try:
        r = os.path.relpath(path, ROOT)
    except ValueError:
        return path
    return path if r.startswith("..") else r


def strip_code_spans(line):
    """The line with the contents of `code spans` blanked (same length, so columns hold)."""
    out = []
    i = 0
    n = len(line)
    while i < n:
        if line[i] == "`":
            j = i
            while j < n and line[j] == "`":
                j += 1
            ticks = line[i:j]
            end = line.find(ticks, j)
            # A closing run must be exactly as long: skip longer runs.
            while end != -1 and end + len(ticks) < n and line[end + len(ticks)] == "`":
                end = line.find(ticks, end + len(ticks) + 1)
            if end == -1:
                out.append(line[i:j])
                i = j
                continue
            out.append(" " * (end + len(ticks) - i))
            i = end + len(ticks)
        else:
            out.append(line[i])
            i += 1
    return "".join(out)


def outside_fences(text):
    """(line number, line) for every line of markdown outside fenced code blocks."""
    fence = None
    for number, line in enumerate(text.split("\n"), 1):
        if fence is None:
            m = FENCE.match(line)
            if m:
                fence = m.group(1)
                continue
            yield number, line
        else:
            s = line.strip()
            if s and set(s) == {fence[0]} and len(s) >= len(fence):
                fence = None


def markdown_lines(text):
    """(line number, line) outside fenced code blocks, with code spans blanked."""
    for number, line in outside_fences(text):
        yield number, strip_code_spans(line)


def heading_text(raw):
    """The text GitHub renders for a heading's markdown source."""
    text = raw
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links and images: their text
    text = re.sub(r"<[^>]+>", "", text)  # inline HTML tags
    text = text.replace("`", "")
    text = re.sub(r"(\*\*|__)(.+?)\1", r"\2", text)
    text = re.sub(r"(?<![\w*])\*(?!\s)(.+?)(?<!\s)\*(?![\w*])", r"\1", text)
    text = re.sub(r"(?<![\w_])_(?!\s)(.+?)(?<!\s)_(?![\w_])", r"\1", text)
    text = re.sub(r"\\(.)", r"\1", text)
    for entity, char in (("&amp;", "&"), ("&lt;", "<"), ("&gt;", ">"), ("&quot;", '"')):
        text = text.replace(entity, char)
    return text.strip()


def slug(text):
    """GitHub's anchor for a heading's rendered text."""
    out = []
    for ch in text.lower():
        if ch.isalnum() or ch in "-_":
            out.append(ch)
        elif ch == " ":
            out.append("-")
    return "".join(out)


def expand_includes(path, seen=None):
    """A markdown file's text with mdBook's plain {{#include FILE}} lines expanded."""
    seen = set() if seen is None else seen
    with open(path, encoding="utf-8") as f:
        text = f.read()
    if path in seen:
        return text
    seen = seen | {path}

    def one(m):
        target = os.path.normpath(os.path.join(os.path.dirname(path), m.group(1).split(":")[0]))
        if os.path.isfile(target) and target.endswith(".md"):
            return expand_includes(target, seen)
        return m.group(0)

    return INCLUDE.sub(one, text)


_anchor_cache = {}


def markdown_anchors(path):
    """Every anchor a link may use in a markdown file: heading slugs and explicit ids."""
    if path in _anchor_cache:
        return _anchor_cache[path]
    anchors = set()
    counts = {}
    text = expand_includes(path)
    for _, line in outside_fences(text):
        h = ATX.match(line)
        if h and h.group(2) is not None:
            base = slug(heading_text(h.group(2)))
            n = counts.get(base, 0)
            anchors.add(base if n == 0 else "%s-%d" % (base, n))
            counts[base] = n + 1
        for m_id in HTML_ID.finditer(line):
            anchors.add(m_id.group(1)[1:-1])
    _anchor_cache[path] = anchors
    return anchors


class _HtmlScan(html.parser.HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.links = []  # (line, attribute value)
        self.ids = set()
        self.base = None
        self.text = []  # (line, shown text, inside <code>)
        self._code = 0
        self._hidden = 0  # inside <script> or <style>

    def handle_endtag(self, tag):
        if tag == "code":
            self._code = max(0, self._code - 1)
        elif tag in ("script", "style"):
            self._hidden = max(0, self._hidden - 1)

    def handle_data(self, data):
        if not self._hidden:
            self.text.append((self.getpos()[0], data, self._code > 0))

    def handle_starttag(self, tag, attrs):
        if tag == "code":
            self._code += 1
        elif tag in ("script", "style"):
            self._hidden += 1
        attrs = dict(attrs)
        for key in ("id", "name"):
            if attrs.get(key):
                self.ids.add(attrs[key])
        if tag == "base" and attrs.get("href"):
            self.base = attrs["href"]
        elif tag == "a" and attrs.get("href") is not None:
            self.links.append((self.getpos()[0], attrs["href"]))
        elif tag == "img" and attrs.get("src") is not None:
            self.links.append((self.getpos()[0], attrs["src"]))

    def handle_startendtag(self, tag, attrs):
        # A self-closing tag opens nothing.
        if tag not in ("code", "script", "style"):
            self.handle_starttag(tag, attrs)


_html_cache = {}


def scan_html(path):
    if path not in _html_cache:
        scan = _HtmlScan()
        with open(path, encoding="utf-8", errors="replace") as f:
            scan.feed(f.read())
        scan.close()
        _html_cache[path] = scan
    return _html_cache[path]


def check_target(source, dest, top, roots):
    """Why `dest`, linked from the file `source`, is broken; None when it resolves.

    `top` is the directory a leading '/' refers to; `roots` the directories a target may
    lie in."""
    if not dest or SCHEME.match(dest):
        return None
    if dest.startswith("<") and dest.endswith(">"):
        dest = dest[1:-1]
    part, _, anchor = dest.partition("#")
    part = urllib.parse.unquote(part.split("?", 1)[0])
    anchor = urllib.parse.unquote(anchor)
    if part == "":
        target = source
    elif part.startswith("/"):
        target = os.path.normpath(os.path.join(top, part.lstrip("/")))
    else:
        target = os.path.normpath(os.path.join(os.path.dirname(source), part))
    real = os.path.realpath(target)
    if not any(real == r or real.startswith(r + os.sep) for r in roots):
        return "leaves the repository" if roots == [ROOT] else "leaves the book"
    if not os.path.exists(target):
        return "no such file"
    if not anchor:
        return None
    if os.path.isdir(target):
        return "an anchor on a directory"
    if target.endswith(".md"):
        if anchor in markdown_anchors(target):
            return None
        return "no heading or id #%s in %s" % (anchor, rel(target))
    if target.endswith((".html", ".htm")):
        if anchor in scan_html(target).ids:
            return None
        return "no id #%s in %s" % (anchor, rel(target))
    if GITHUB_LINE.match(anchor):
        return None
    return "an anchor #%s on a file that has none" % anchor


def check_markdown(path, problems):
    with open(path, encoding="utf-8") as f:
        text = f.read()
    refs = {}
    lines = list(markdown_lines(text))
    for number, line in lines:
        m = REFDEF.match(line)
        if m and not m.group(1).startswith("^"):
            refs[m.group(1).lower()] = (number, m.group(2))
    found = []
    for number, line in lines:
        for m in INLINE.finditer(line):
            found.append((number, m.group(2)))
        for m in HTML_ATTR.finditer(line):
            found.append((number, m.group(1)[1:-1]))
        includes = [m.group(1) for m in INCLUDE.finditer(line)]
        book_include = BOOK_INCLUDE.match(line)
        if book_include:
            includes.append(book_include.group(1))
        for target in includes:
            target = target.split(":")[0]
            if not os.path.isfile(os.path.join(os.path.dirname(path), target)):
                problems.append("%s:%d: %s: included file not found" % (rel(path), number, target))
    found.extend(refs.values())
    for number, dest in found:
        why = check_target(path, dest.strip(), ROOT, [ROOT])
        if why:
            problems.append("%s:%d: %s: %s" % (rel(path), number, dest, why))
    return len(found)


def check_html(path, book, problems):
    scan = scan_html(path)
    count = 0
    base_dir = os.path.dirname(path)
    if scan.base and not SCHEME.match(scan.base):
        if scan.base.startswith("/"):
            base_dir = os.path.join(book, scan.base.lstrip("/"))
        else:
            base_dir = os.path.join(base_dir, scan.base)
    for number, dest in scan.links:
        dest = dest.strip()
        if dest in ("", "#") or SCHEME.match(dest):
            continue
        count += 1
        # Resolve against the page's <base> when it has one (mdBook's 404 page).
        source = os.path.join(base_dir, os.path.basename(path)) if dest[0] != "#" else path
        # The built book must stand alone: nothing may resolve outside its own directory
        # (scripts/build_book.sh copies or turns into URLs what the guide links outside it).
        why = check_target(source, dest, book, [os.path.realpath(book)])
        if why:
            problems.append("%s:%d: %s: %s" % (rel(path), number, dest, why))
    return count


def check_shown_text(path, book, problems):
    """An en dash before a lowercase letter anywhere on the page; an entity shown as typed
    inside code on the generated reference pages."""
    scan = scan_html(path)
    reference = os.path.relpath(path, book) in REFERENCE_PAGES
    for number, data, in_code in scan.text:
        for m in DASHED_FLAG.finditer(data):
            snippet = data[max(0, m.start() - 20) : m.end() + 20].replace("\n", " ")
            problems.append(
                "%s:%d: ...%s...: an en dash before a word (smart punctuation's `--`?)"
                % (rel(path), number, snippet)
            )
        if reference and in_code:
            for m in SHOWN_ENTITY.finditer(data):
                snippet = data[max(0, m.start() - 20) : m.end() + 20].replace("\n", " ")
                problems.append(
                    "%s:%d: `%s`: code shows the entity %s as typed"
                    % (rel(path), number, snippet, m.group(0))
                )


def main(argv):
    if len(argv) > 2 or (len(argv) == 2 and argv[1] in ("-h", "--help")):
        print(__doc__.strip())
        return 0 if len(argv) == 2 else 2
    problems = []
    files = [os.path.join(ROOT, "README.md")]
    guide = os.path.join(ROOT, "docs", "guide")
    for dirpath, dirnames, filenames in os.walk(guide):
        dirnames.sort()
        files.extend(os.path.join(dirpath, n) for n in sorted(filenames) if n.endswith(".md"))
    links = sum(check_markdown(f, problems) for f in files)
    checked = "%d markdown files" % len(files)
    if len(argv) == 2:
        book = os.path.abspath(argv[1])
        pages = []
        for dirpath, dirnames, filenames in os.walk(book):
            dirnames.sort()
            pages.extend(os.path.join(dirpath, n) for n in sorted(filenames) if n.endswith(".html"))
        if not pages:
            problems.append("%s: no .html files (build the book first: scripts/build_book.sh)" % argv[1])
        links += sum(check_html(p, book, problems) for p in pages)
        for p in pages:
            check_shown_text(p, book, problems)
        for page in REFERENCE_PAGES:
            if pages and not os.path.isfile(os.path.join(book, page)):
                problems.append("%s: missing from the built book" % os.path.join(argv[1], page))
        checked += " and %d HTML pages" % len(pages)
    for p in problems:
        print(p)
    if problems:
        print("%d problem(s) in %s" % (len(problems), checked))
        return 1
    print("%d relative links in %s: all resolve" % (links, checked))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
