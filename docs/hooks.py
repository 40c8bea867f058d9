"""mkdocs hooks of the docs site (``mkdocs.yml``): pages that live outside ``docs/`` join the site as they are.

* The README is the home page (``index.md``); its links into ``docs/`` are rewritten to the site's paths.
* ``docs/index.md``, the generated list of environments, becomes ``environments.md``.
* The papers' reproductions come from ``results/`` (``make demo`` writes them): ``REPORT.md`` and the figures and
  tables beside it, under ``reproductions/``. Without ``results/REPORT.md`` the build stops and says to run
  ``make demo``.
"""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
#: what of results/ the site shows: the report and what it links to
RESULT_SUFFIXES = (".md", ".png", ".gif", ".csv", ".json")


def readme_for_site(text: str) -> str:
    """The README with its links into ``docs/`` pointing at the site's pages."""
    text = text.replace("](docs/index.md)", "](environments.md)")
    return re.sub(r"\]\(docs/", "](", text)


def on_files(files: Files, config) -> Files:
    listing = files.get_file_from_path("index.md")
    if listing is not None:
        files.remove(listing)
        files.append(File.generated(config, "environments.md", content=Path(listing.abs_src_path).read_text()))
    files.append(File.generated(config, "index.md", content=readme_for_site((ROOT / "README.md").read_text())))
    report = RESULTS / "REPORT.md"
    if not report.exists():
        raise PluginError(f"{report} is missing: run `make demo` first (it reproduces the papers into results/)")
    for path in sorted(RESULTS.rglob("*")):
        relative = path.relative_to(RESULTS)
        # cached Monte-Carlo tasks and sweep bookkeeping are not for readers
        if path.is_file() and path.suffix in RESULT_SUFFIXES and "tasks" not in relative.parts:
            files.append(File.generated(config, f"reproductions/{relative.as_posix()}", abs_src_path=str(path)))
    return files
