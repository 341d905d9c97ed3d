#!/usr/bin/env bash
# Build the user guide as a self-contained HTML book in target/book.
#
#     scripts/build_book.sh            # then: python3 scripts/check_links.py target/book
#
# docs/guide is the book's source, but its pages link to files elsewhere in the repository
# (the paper's report and figures in docs/paper, docs/figures, experiments' directories).
# scripts/stage_book.py copies the guide to target/book-src, copies the images and the
# paper's pages it shows into target/book-src/guide/repository/ (rewriting those links), and
# turns every other link out of the guide into a URL of the repository's source. mdBook then
# builds target/book-src into target/book: the result can be copied or hosted anywhere.
# Needs python3 and mdbook (0.5.x) on PATH.
set -euo pipefail
cd "$(dirname "$0")/.."
# Always under ./target (not $CARGO_TARGET_DIR), where docs/book.toml puts the book too.
python3 scripts/stage_book.py target/book-src
rm -rf target/book
mdbook build target/book-src -d "$(pwd)/target/book"
