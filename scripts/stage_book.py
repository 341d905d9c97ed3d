#!/usr/bin/env python3
"""Stage the user guide into a self-contained mdBook source tree.

    python3 scripts/stage_book.py [STAGE]      # STAGE defaults to target/book-src

The guide's pages (docs/guide) link to files elsewhere in the repository with relative paths
(`../../../docs/paper/report.md`, `../../../docs/figures/x.png`), which work on GitHub and in
a checkout but leave a built book. This script copies docs/book.toml and docs/guide to STAGE
(STAGE/book.toml, STAGE/guide) and rewrites every relative link, image and `{{#include}}` of
every page whose target lies outside docs/guide:

- an image (.png, .jpg, .jpeg, .gif, .svg, .webp) or an included file is copied to
  STAGE/guide/repository/<its path in the repository>, and the link points to the copy;
- a markdown file under docs/paper/ (the paper's report and tables) is copied there as well,
  its own links rewritten the same way, and added to the staged SUMMARY.md as a sub-chapter of
  the first page that links to it, so that mdBook renders it;
- a line `<!-- book-include: PATH -->` (PATH relative to the page, outside the guide) becomes
  mdBook's `{{#include}}` of the copied file: the book shows the file's text, GitHub shows
  nothing there (the page should link the file too); the included text's own links are not
  rewritten, so include only files without relative links (docs/paper/table1.md);
- anything else (a directory, source code, an experiment's directory) becomes a link to the
  repository's source by URL: `[workspace.package] repository` of Cargo.toml, then
  /tree/main/<path> for a directory or /blob/main/<path> for a file.

Links inside docs/guide, links with a scheme and links in code are left as they are. Links
are found line by line, as scripts/check_links.py finds them: one whose text is split over
two lines is not rewritten, and check_links.py on the built book then fails on it. Nothing
is written outside STAGE; the copies are never committed (target/ is ignored). Build the book
with scripts/build_book.sh, which runs this and then mdBook on STAGE. Python 3 standard
library only.
"""

import os
import re
import shutil
import sys
from urllib.parse import unquote

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import check_links  # noqa: E402  (same directory: the link syntax is parsed the same way)

ROOT = check_links.ROOT
DOCS = os.path.join(ROOT, "docs")
GUIDE = os.path.join(DOCS, "guide")
COPY_DIR = "repository"
IMAGE_EXT = (".png", ".jpg", ".jpeg", ".gif", ".svg", ".webp")
# Markdown outside the guide that the book renders as chapters of its own.
CHAPTER_DIRS = (os.path.join(DOCS, "paper"),)
BRANCH = "main"
# A book-only include: GitHub hides the comment (the page links the file beside it for GitHub
# readers); the staged copy replaces it with mdBook's {{#include}} of the copied file.
BOOK_INCLUDE = re.compile(r"^<!--\s*book-include:\s*(\S+)\s*-->\s*$")
SUMMARY_ENTRY = re.compile(r"^(\s*)[-*]\s+\[[^\]]*\]\(([^)]+)\)")


def repository_url():
    """`repository` of Cargo.toml's [workspace.package]."""
    section = None
    with open(os.path.join(ROOT, "Cargo.toml"), encoding="utf-8") as f:
        for line in f:
            s = line.strip()
            if s.startswith("["):
                section = s
            elif section == "[workspace.package]":
                m = re.match(r'repository\s*=\s*"([^"]+)"', s)
                if m:
                    return m.group(1).rstrip("/")
    sys.exit("stage_book.py: no repository in Cargo.toml's [workspace.package]")


def inside(path, directory):
    return path == directory or path.startswith(directory + os.sep)


def title_of(path):
    with open(path, encoding="utf-8") as f:
        for _, line in check_links.outside_fences(f.read()):
            h = check_links.ATX.match(line)
            if h and h.group(2):
                return check_links.heading_text(h.group(2)).replace("]", "\\]")
    return os.path.relpath(path, ROOT).replace(os.sep, "/")


class Stage:
    def __init__(self, stage):
        self.stage = stage
        self.guide = os.path.join(stage, "guide")
        self.url = repository_url()
        self.chapters = []  # (original path, original path of the page that first links it)
        self.copied = set()
        self.queue = []

    def staged_path(self, original):
        """Where an original file lies in the staged guide."""
        if inside(original, GUIDE):
            return os.path.join(self.guide, os.path.relpath(original, GUIDE))
        return os.path.join(self.guide, COPY_DIR, os.path.relpath(original, ROOT))

    def copy(self, original, linked_from, chapter):
        if original in self.copied:
            return
        self.copied.add(original)
        if chapter:
            self.chapters.append((original, linked_from))
            self.queue.append(original)
        else:
            dest = self.staged_path(original)
            os.makedirs(os.path.dirname(dest), exist_ok=True)
            shutil.copy2(original, dest)

    def rewrite(self, dest, original_page, include=False):
        """The replacement for one link destination of `original_page`; None: keep it."""
        bracketed = dest.startswith("<") and dest.endswith(">")
        raw = dest[1:-1] if bracketed else dest
        if not raw or check_links.SCHEME.match(raw) or raw.startswith("#") or raw.startswith("/"):
            return None
        if include:
            part, sep, rest = raw.partition(":")
        else:
            part, sep, rest = raw.partition("#")
        path = part.split("?", 1)[0]

        target = os.path.normpath(os.path.join(os.path.dirname(original_page), unquote(path)))
        if not inside(target, ROOT) or not os.path.exists(target):
            return None  # broken or outside the repository: check_links.py reports it
        here = os.path.dirname(self.staged_path(original_page))
        if inside(target, GUIDE):
            if inside(original_page, GUIDE):
                return None  # within the guide: the staged copy keeps the same layout
            new = os.path.relpath(self.staged_path(target), here)
        elif include or (os.path.isfile(target) and target.lower().endswith(IMAGE_EXT)):
            self.copy(target, original_page, chapter=False)
            new = os.path.relpath(self.staged_path(target), here)
        elif (os.path.isfile(target) and target.endswith(".md")
              and any(inside(target, d) for d in CHAPTER_DIRS)):
            self.copy(target, original_page, chapter=True)
            new = os.path.relpath(self.staged_path(target), here)
        else:
            kind = "tree" if os.path.isdir(target) else "blob"
            rel_target = os.path.relpath(target, ROOT).replace(os.sep, "/")
            new = "%s/%s/%s/%s" % (self.url, kind, BRANCH, rel_target)
        new = new.replace(os.sep, "/")
        if path.endswith("/") and not new.endswith("/"):
            new += "/"
        new = new + sep + rest
        return "<%s>" % new if bracketed else new

    def stage_markdown(self, original):
        """Write the staged copy of one markdown page with its outward links rewritten."""
        with open(original, encoding="utf-8") as f:
            text = f.read()
        lines = text.split("\n")
        for number, blanked in check_links.markdown_lines(text):
            line = lines[number - 1]
            edits = []  # (start, end, replacement)
            for m in check_links.INLINE.finditer(blanked):
                new = self.rewrite(m.group(2), original)
                if new is not None:
                    edits.append((m.start(2), m.end(2), new))
            for m in check_links.HTML_ATTR.finditer(blanked):
                new = self.rewrite(m.group(1)[1:-1], original)
                if new is not None:
                    edits.append((m.start(1) + 1, m.end(1) - 1, new))
            for m in check_links.INCLUDE.finditer(blanked):
                new = self.rewrite(m.group(1), original, include=True)
                if new is not None:
                    edits.append((m.start(1), m.end(1), new))
            m = BOOK_INCLUDE.match(blanked)
            if m:
                new = self.rewrite(m.group(1), original, include=True)
                if new is None:
                    sys.exit("stage_book.py: %s:%d: book-include of a missing file or one inside "
                             "the guide: %s" % (check_links.rel(original), number, m.group(1)))
                lines[number - 1] = "{{#include %s}}" % new
                continue
            m = check_links.REFDEF.match(blanked)
            if m and not m.group(1).startswith("^"):
                new = self.rewrite(m.group(2), original)
                if new is not None:
                    edits.append((m.start(2), m.end(2), new))
            for start, end, new in sorted(edits, reverse=True):
                line = line[:start] + new + line[end:]
            lines[number - 1] = line
        dest = self.staged_path(original)
        os.makedirs(os.path.dirname(dest), exist_ok=True)
        with open(dest, "w", encoding="utf-8") as f:
            f.write("\n".join(lines))

    def summary(self):
        """Add every copied markdown file to the staged SUMMARY.md under the page linking it."""
        path = os.path.join(self.guide, "SUMMARY.md")
        with open(path, encoding="utf-8") as f:
            lines = f.read().split("\n")
        for original, parent in self.chapters:
            parent_link = os.path.relpath(self.staged_path(parent), self.guide).replace(os.sep, "/")
            for i, line in enumerate(lines):
                m = SUMMARY_ENTRY.match(line)
                if m and m.group(2).split("#")[0] == parent_link:
                    link = os.path.relpath(self.staged_path(original), self.guide).replace(os.sep, "/")
                    entry = "%s  - [%s](%s)" % (m.group(1), title_of(original), link)
                    lines.insert(i + 1, entry)
                    break
            else:
                sys.exit("stage_book.py: %s is linked from %s, which SUMMARY.md does not list"
                         % (check_links.rel(original), check_links.rel(parent)))
        with open(path, "w", encoding="utf-8") as f:
            f.write("\n".join(lines))

    def run(self):
        if os.path.exists(self.stage):
            shutil.rmtree(self.stage)
        shutil.copytree(GUIDE, self.guide, ignore=shutil.ignore_patterns("*.md"))
        shutil.copy2(os.path.join(DOCS, "book.toml"), os.path.join(self.stage, "book.toml"))
        for dirpath, dirnames, filenames in os.walk(GUIDE):
            dirnames.sort()
            for name in sorted(filenames):
                if name.endswith(".md"):
                    self.stage_markdown(os.path.join(dirpath, name))
        while self.queue:
            self.stage_markdown(self.queue.pop(0))
        self.summary()
        return len(self.copied)


def main(argv):
    if len(argv) > 2 or (len(argv) == 2 and argv[1] in ("-h", "--help")):
        print(__doc__.strip())
        return 0 if len(argv) == 2 else 2
    stage = os.path.abspath(argv[1] if len(argv) == 2 else os.path.join(ROOT, "target", "book-src"))
    if inside(stage, DOCS) or stage == ROOT:
        sys.exit("stage_book.py: the stage must not be the repository or lie under docs/")
    n = Stage(stage).run()
    print("staged the guide in %s with %d file(s) from outside it" % (check_links.rel(stage), n))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
