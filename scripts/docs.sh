#!/usr/bin/env bash
# Build the documentation site (MkDocs Material, the docs extra) with --strict: a broken link,
# a missing anchor or a page left out of the nav fails the build. Run from anywhere inside the
# venv; the site goes to ${1:-site} (ignored by git).
set -euo pipefail
cd "$(dirname "$0")/.."
mkdocs build --strict --site-dir "${1:-site}"
