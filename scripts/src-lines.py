#!/usr/bin/env python3
"""Lines of the product's src/ at a git revision, the measure issue 15 uses for "src/ does not
grow": code+comments outside tests (`#[cfg(test)] mod` blocks and `tests.rs` files left out),
the code, comment and blank lines among them, and the test lines. src/scene (moved to tools/scene) is left out.
Usage: scripts/src-lines.py REV [REV...]"""
import re
import subprocess
import sys

for rev in sys.argv[1:] or ["HEAD"]:
    files = subprocess.run(["git", "ls-tree", "-r", "--name-only", rev, "src"],
                           capture_output=True, text=True, check=True).stdout.split()
    code = comments = blank = tests = 0
    for f in files:
        if not f.endswith(".rs") or f.startswith("src/scene"):
            continue
        lines = subprocess.run(["git", "show", f"{rev}:{f}"], capture_output=True,
                               text=True, check=True).stdout.split("\n")
        if f.endswith("/tests.rs"):
            tests += len(lines)
            continue
        i = 0
        while i < len(lines):
            if (lines[i].strip() == "#[cfg(test)]" and i + 1 < len(lines)
                    and re.match(r"^mod \w+ \{", lines[i + 1])):
                j = i + 2
                while j < len(lines) and lines[j] != "}":
                    j += 1
                tests += j - i + 1
                i = j + 1
                continue
            code += 1
            comments += lines[i].strip().startswith("//")
            blank += lines[i].strip() == ""
            i += 1
    print(f"{rev}: code+comments {code} (code {code - comments - blank}, comments {comments}, "
          f"blank {blank}), tests {tests}")
