#!/usr/bin/env python3
"""Check that README, the user guide and the experiments' reports quote the paper's arms with the
paper's numbers.

    python3 scripts/check_numbers.py            # README.md, docs/guide (not reference/), docs/experiments
    python3 scripts/check_numbers.py FILE...    # those markdown files only
    python3 scripts/check_numbers.py --list [FILE...]   # also every quote found, with its verdict

docs/paper/results.json ("paper" -> "table1") holds the current Table I: per planner and
speed cap, the success (% of runs) and score of the arms vanilla, DDP, best constant and ADP,
and ADP's score and success differences with DDP and the best constant. A page that quotes one
of these for a planner and speed with another value says something the paper no longer
supports, unless the page says visibly that it is superseded (a line, outside code and HTML
comments, with the word "superseded" that is not "not superseded"; the guide's convention is a
quote at the top: "> **Superseded by [the paper's tables](paper.md)** ..., and why the numbers
differ"). A page whose rows look like the paper's arms but measure something else (other
test worlds, an ADP trained with another learner setting) says so the same way: a quote that
opens with "> **Not the paper's ...**" and names the paper's numbers.

A table whose caption begins "Recipe `NAME`" (the paper's rows of another training recipe,
"paper" -> "recipes") is checked against that recipe's Table I.

The experiments' reports under docs/experiments are checked too: `adp experiment` writes each
as the record of its own protocol, and one whose numbers the paper has since replaced carries
the same kind of note at its top, under its title (the numbers themselves are left as
measured). In their tables the speed is the bare number that ends a column header ("success
(%) ↑ 1.5").

What counts as a quote, kept narrow so that the check does not guess:

- a markdown table cell whose row label or column header names an arm (vanilla, DDP,
  DWA-DDP, best constant, ADP; not state-shuffled, untrained or PADP) and a metric (a column
  "success" or "score", or a cell "95.5 % / 0.470" under an arm's column), or a difference
  column ("ADP − DDP score", "Δ score", "Δ success (pp)") on a DDP or best-constant row;
  the planner and speed come from the row's planner and speed columns, else the row label and
  column header, else the table's caption, the section's heading or the page's title;
- a prose line with an arm followed within a few words by "NN.N %" (and optionally
  "/ 0.NNN" or ", 0.NNN" for the score), the planner and speed taken from the line, else its
  paragraph, else the section or the page title.

A level that names two planners or two speeds is ambiguous: the quote is skipped, not
guessed. A quoted value matches when it equals the current one rounded to the decimals it is
written with. Exit status 1 with one line per mismatch (`FILE:LINE: ...`), 0 otherwise.
Python 3 standard library only.
"""

import json
import os
import re
import sys

ROOT = os.path.realpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
RESULTS = os.path.join(ROOT, "docs", "paper", "results.json")

FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
HEADING = re.compile(r"^ {0,3}#{1,6}\s+(.*)$")
PLANNER = re.compile(r"(?<![\w-])(log-mppi|mppi|dwa|system)(?![\w])", re.I)
SPEED = re.compile(r"(?<![\d.])([0-9]\.[0-9])\s*m/s")
# An experiment report's column header ends with the speed cap alone: "success (%) ↑ 1.5".
HEADER_SPEED = re.compile(r"(?<![\d.])([0-9]\.[0-9])\s*$")
SUPERSEDED = re.compile(r"(?<!not )\bsuperseded\b", re.I)
# The note of a page whose rows look like the paper's arms but are not (other worlds, another
# learner setting): a quote that opens with it in bold.
NOT_PAPERS = re.compile(r"^\s*>\s*\*\*Not the paper's\b")
# A table of another training recipe's rows: its caption names the recipe.
RECIPE = re.compile(r"\s*Recipe `([\w-]+)`")
NUMBER = re.compile(r"(?<![\w.])([+\-−]?)(\d+(?:\.\d+)?)")
CELL_PAIR = re.compile(r"^\**\s*(\d{1,3}(?:\.\d+)?)\s*%\s*/\s*(\d\.\d+)")
DIFF = re.compile(r"(ADP\s*[−–-]\s*(DDP|(?:best\s+)?constant|vanilla)|Δ)", re.I)
# Labels that name an arm but mean another thing: a control derived from it, a single seed, an
# action space other than the paper's decremental one ("ADP-velocity", "best constant
# (weights:dwa)").
NOT_ARM = re.compile(r"shuffled|untrained|initiali[sz]ed|PADP|KFRes|random|\bseeds? \d"
                     r"|velocity|weights|incremental|unconstrained", re.I)
# An experiment's arm id as its report names it: planner-space-speed-worlds
# ("dwa-decremental-1.5-fit"); only the decremental space is the paper's.
ARM_ID = re.compile(r"(?<![\w-])(log-mppi|mppi|dwa|system)-([\w:+]+)-([0-9]\.[0-9])-\S+")
# A prose quote: an arm, a few words, then a success in % (and perhaps its score).
PROSE = re.compile(
    r"(?<![\w−–-])(?<![−–-] )(best constant|vanilla|DDP|ADP)(?:'s)?\b"
    r"((?:\s+|\s*\(|\s+[a-z]+\s+){0,3}?)"
    r"(?<![+\-−\d.])(\d{1,3}\.\d+)\s?%(?:\s*(?:/|,)\s*(0\.\d{2,4}))?"
)


def planners_in(text):
    return {m.group(1).lower() for m in PLANNER.finditer(text)}


def speeds_in(text):
    return {float(m.group(1)) for m in SPEED.finditer(text)}


def arm_of(label):
    """The arm a row label or column header names, 'diff:<control>' for a difference column,
    None for none or several."""
    if NOT_ARM.search(label):
        return None
    m = DIFF.search(label)
    if m:
        other = (m.group(2) or "").lower()
        if "constant" in other:
            return "diff:constant"
        if other == "ddp":
            return "diff:ddp"
        return "diff:" if m.group(0) == "Δ" else None
    arms = set()
    if re.search(r"best\s+constant", label, re.I):
        arms.add("constant")
    if re.search(r"\bvanilla\b", label, re.I):
        arms.add("vanilla")
    if re.search(r"(?<![A-Za-z])DDP\b", label):
        arms.add("ddp")
    if re.search(r"(?<![A-Za-z])ADP\b", label):
        arms.add("adp")
    return arms.pop() if len(arms) == 1 else None


def metric_of(header):
    h = header.lower()
    if any(w in h for w in ("collision", "time", "compute", "sd", "only", "p =", "seeds")):
        return None
    if "success" in h:
        return "success"
    if "score" in h:
        return "score"
    return None


def decimals(text):
    return len(text.split(".")[1]) if "." in text else 0


def matches(quoted, current):
    """Whether the quoted text is the current value rounded to the quoted decimals."""
    value = float(quoted.replace("−", "-"))
    d = decimals(quoted.lstrip("+-−"))
    return abs(value - current) <= 0.5 * 10 ** (-d) + 1e-9


class Paper:
    def __init__(self, path=RESULTS):
        with open(path, encoding="utf-8") as f:
            paper = json.load(f)["paper"]
        self.cells = self.read(paper["table1"])
        self.recipes = {r["name"]: self.read(r["table1"]) for r in paper.get("recipes", [])}

    @staticmethod
    def read(table1):
        """(planner, speed) -> {(arm, metric): value} of one Table I."""
        cells = {}
        for cell in table1:
            values = {}
            for arm in ("vanilla", "ddp", "constant", "adp"):
                row = cell.get(arm)
                if isinstance(row, dict):
                    values[(arm, "success")] = row["success_pct"]
                    values[(arm, "score")] = row["score"]
            for control in ("ddp", "constant"):
                diff = cell.get("adp_vs_" + control)
                if isinstance(diff, dict):
                    values[("diff:" + control, "score")] = diff["d_score"]["mean"]
                    values[("diff:" + control, "success")] = 100.0 * diff["d_success"]["mean"]
            cells[(cell["planner"], round(float(cell["speed"]), 1))] = values
        return cells

    def value(self, planner, speed, arm, metric, recipe=None):
        cells = self.cells if recipe is None else self.recipes.get(recipe, {})
        return cells.get((planner, speed), {}).get((arm, metric))


def strip_code(line):
    return re.sub(r"`[^`]*`", lambda m: " " * len(m.group(0)), line)


def split_row(line):
    s = line.strip()
    if s.startswith("|"):
        s = s[1:]
    if s.endswith("|"):
        s = s[:-1]
    return [c.strip() for c in re.split(r"(?<!\\)\|", s)]


def is_rule(cells):
    return all(re.fullmatch(r":?-{3,}:?", c) for c in cells if c) and any(cells)


class Page:
    """A markdown page as lines outside code fences and HTML comments, with its structure."""

    def __init__(self, path):
        self.path = path
        with open(path, encoding="utf-8") as f:
            raw = f.read().split("\n")
        self.raw = raw  # the lines as written (line number n at n - 1)
        self.lines = []  # (number, text) with code spans blanked; fenced lines are ""
        fence = None
        comment = False
        for number, line in enumerate(raw, 1):
            if fence is not None:
                s = line.strip()
                if s and set(s) == {fence[0]} and len(s) >= len(fence):
                    fence = None
                self.lines.append((number, ""))
                continue
            m = FENCE.match(line)
            if m:
                fence = m.group(1)
                self.lines.append((number, ""))
                continue
            text = line
            if comment:
                end = text.find("-->")
                if end == -1:
                    self.lines.append((number, ""))
                    continue
                text = " " * (end + 3) + text[end + 3 :]
                comment = False
            text = re.sub(r"<!--.*?-->", lambda m: " " * len(m.group(0)), text)
            start = text.find("<!--")
            if start != -1:
                text = text[:start]
                comment = True
            self.lines.append((number, strip_code(text)))
        self.title = next((HEADING.match(t).group(1) for _, t in self.lines if HEADING.match(t)), "")
        self.superseded = any(SUPERSEDED.search(t) or NOT_PAPERS.match(t) for _, t in self.lines)

    def heading_before(self, index):
        for i in range(index, -1, -1):
            m = HEADING.match(self.lines[i][1])
            if m:
                return i, m.group(1)
        return 0, ""

    def paragraph(self, index):
        lo = index
        while lo > 0 and self.lines[lo - 1][1].strip() and not HEADING.match(self.lines[lo - 1][1]):
            lo -= 1
        hi = index
        while hi + 1 < len(self.lines) and self.lines[hi + 1][1].strip():
            hi += 1
        return " ".join(t for _, t in self.lines[lo : hi + 1]), lo

    def recipe(self, table_start):
        """The training recipe a table's caption names ("Recipe `NAME`"), if any."""
        i = table_start - 1
        while i >= 0 and not self.lines[i][1].strip():
            i -= 1
        if i < 0:
            return None
        _, lo = self.paragraph(i)
        m = RECIPE.match(self.raw[self.lines[lo][0] - 1])
        return m.group(1) if m else None

    def caption(self, table_start):
        """The paragraph just before a table (its caption), if any."""
        i = table_start - 1
        while i >= 0 and not self.lines[i][1].strip():
            i -= 1
        if i < 0 or self.lines[i][1].lstrip().startswith("|") or HEADING.match(self.lines[i][1]):
            return ""
        return self.paragraph(i)[0]


def resolve(levels):
    """Planner and speed from the first level that names them; None when a level is ambiguous
    before both are known."""
    planner = speed = None
    for text in levels:
        if planner is None:
            p = planners_in(text)
            if len(p) > 1:
                return None, None
            if p:
                planner = p.pop()
        if speed is None:
            s = speeds_in(text)
            if len(s) > 1:
                return None, None
            if s:
                speed = s.pop()
        if planner and speed is not None:
            return planner, speed
    return None, None


def check_page(path, paper, problems, listing=None):
    page = Page(path)
    quotes = []  # (line number, planner, speed, arm, metric, quoted text, recipe or None)
    lines = page.lines
    i = 0
    while i < len(lines):
        text = lines[i][1]
        if (text.lstrip().startswith("|") and i + 1 < len(lines)
                and is_rule(split_row(lines[i + 1][1]))):
            start = i
            header = split_row(text)
            i += 2
            rows = []
            while i < len(lines) and lines[i][1].lstrip().startswith("|"):
                rows.append((lines[i][0], split_row(lines[i][1])))
                i += 1
            h_index, heading = page.heading_before(start)
            arm_id = ARM_ID.search(heading)
            if arm_id:
                if arm_id.group(2) != "decremental":
                    continue  # another action space's comparisons: not the paper's arm
                heading = "%s %s m/s" % (arm_id.group(1), arm_id.group(3))
            context = [page.caption(start), heading, page.title]
            # A comparison over fewer worlds than the paper's 225 test worlds (a band, the
            # hardest 50) is another quantity than the cell's.
            worlds_col = next((k for k, h in enumerate(header) if h.strip().lower() == "worlds"), None)
            recipe = page.recipe(start)
            planner_col = next((k for k, h in enumerate(header) if "planner" in h.lower()), None)
            speed_col = next((k for k, h in enumerate(header) if "speed" in h.lower()), None)
            for number, cells in rows:
                label = cells[0] if cells else ""
                if (worlds_col is not None and worlds_col < len(cells)
                        and cells[worlds_col].strip() not in ("225", "test")):
                    continue
                row_planner = cells[planner_col].lower() if planner_col is not None and planner_col < len(cells) else None
                row_speed = None
                if speed_col is not None and speed_col < len(cells):
                    m = re.match(r"\**(\d\.\d)", cells[speed_col])
                    row_speed = float(m.group(1)) if m else None
                for k in range(1, min(len(cells), len(header))):
                    head = header[k]
                    if k in (planner_col, speed_col):
                        continue
                    row_arm, col_arm = arm_of(label), arm_of(head)
                    if col_arm and col_arm.startswith("diff:"):
                        # A difference column: on a control's row ("Δ score" on "DDP") or
                        # naming its control ("ADP − DDP score" on a planner's row).
                        if col_arm == "diff:":
                            if row_arm not in ("ddp", "constant"):
                                continue
                            arm = "diff:" + row_arm
                        elif row_arm in (None, "adp"):
                            arm = col_arm
                        else:
                            continue
                    else:
                        if row_arm and col_arm and row_arm != col_arm:
                            continue
                        arm = col_arm or row_arm
                        if arm is None or arm == "diff:":
                            continue
                    planner, speed = resolve(
                        [(row_planner or "") + " " + ("%s m/s" % row_speed if row_speed else ""),
                         label + " " + HEADER_SPEED.sub(r"\1 m/s", head)] + context)
                    if planner is None:
                        continue
                    cell = cells[k]
                    if cell.lstrip("* ").startswith("["):
                        continue  # an interval alone (a second interval column), not a value
                    pair = CELL_PAIR.match(cell)
                    metric = metric_of(head)
                    if pair and metric is None and not arm.startswith("diff:"):
                        quotes.append((number, planner, speed, arm, "success", pair.group(1), recipe))
                        quotes.append((number, planner, speed, arm, "score", pair.group(2), recipe))
                        continue
                    if metric is None and arm.startswith("diff:"):
                        metric = "success" if "pp" in head.lower() or "success" in head.lower() else "score"
                    if metric is None:
                        continue
                    m = NUMBER.search(cell.replace("*", ""))
                    if m:
                        quotes.append((number, planner, speed, arm, metric, m.group(1) + m.group(2), recipe))
            continue
        if text.strip() and not text.lstrip().startswith("|") and not HEADING.match(text):
            for m in PROSE.finditer(text):
                arm = arm_of(m.group(1))
                if arm is None:
                    continue
                paragraph, p_start = page.paragraph(i)
                h_index, heading = page.heading_before(i)
                section = " ".join(t for _, t in lines[h_index + 1 : i + 1])
                planner, speed = resolve([text, paragraph, section, heading, page.title])
                if planner is None:
                    continue
                quotes.append((lines[i][0], planner, speed, arm, "success", m.group(3), None))
                if m.group(4):
                    quotes.append((lines[i][0], planner, speed, arm, "score", m.group(4), None))
        i += 1
    for number, planner, speed, arm, metric, quoted, recipe in quotes:
        current = paper.value(planner, speed, arm, metric, recipe)
        name = {"ddp": "DDP", "adp": "ADP", "constant": "best constant", "vanilla": "vanilla",
                "diff:ddp": "ADP − DDP", "diff:constant": "ADP − best constant"}[arm]
        if listing is not None:
            verdict = ("no such cell" if current is None else "matches" if matches(quoted, current)
                       else "superseded" if page.superseded else "DIFFERS")
            listing.append("%s:%d: %s %.1f m/s %s %s %s: %s"
                           % (os.path.relpath(path, ROOT), number, planner, speed, name, metric,
                              quoted, verdict))
        if current is None or matches(quoted, current):
            continue
        if page.superseded:
            continue
        problems.append(
            "%s:%d: %s %.1f m/s %s %s is %s here, %s in docs/paper/results.json, and the page "
            "has no \"Superseded\" line saying why"
            % (os.path.relpath(path, ROOT), number, planner, speed, name, metric, quoted,
               ("%+.4f" if arm.startswith("diff:") and metric == "score" else "%+.2f"
                if arm.startswith("diff:") else "%.4f" if metric == "score" else "%.2f") % current))
    return len(quotes)


def pages():
    out = [os.path.join(ROOT, "README.md")]
    guide = os.path.join(ROOT, "docs", "guide")
    for dirpath, dirnames, filenames in os.walk(guide):
        dirnames.sort()
        if os.path.relpath(dirpath, guide).split(os.sep)[0] == "reference":
            continue  # generated from the code: no results
        out.extend(os.path.join(dirpath, n) for n in sorted(filenames) if n.endswith(".md"))
    experiments = os.path.join(ROOT, "docs", "experiments")
    for dirpath, dirnames, filenames in os.walk(experiments):
        dirnames.sort()
        out.extend(os.path.join(dirpath, n) for n in sorted(filenames) if n.endswith(".md"))
    return out


def main(argv):
    if len(argv) > 1 and argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    listing = [] if len(argv) > 1 and argv[1] == "--list" else None
    args = argv[2:] if listing is not None else argv[1:]
    paper = Paper()
    files = [os.path.abspath(a) for a in args] or pages()
    problems = []
    quotes = sum(check_page(f, paper, problems, listing) for f in files)
    for line in listing or []:
        print(line)
    for p in problems:
        print(p)
    if problems:
        print("%d quote(s) of the paper's arms disagree with docs/paper/results.json" % len(problems))
        return 1
    print("%d quote(s) of the paper's arms in %d page(s): each matches docs/paper/results.json "
          "or stands on a page marked superseded" % (quotes, len(files)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
