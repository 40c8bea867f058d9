"""The committed docs are exactly what the generator makes from the live environments."""

import re
from pathlib import Path

from PIL import Image

from mrcomm_env.experiments.docs import expected_docs

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"


def test_committed_docs_match_generator():
    stale = [
        str(p.relative_to(DOCS)) for p, text in expected_docs(DOCS).items() if not p.exists() or p.read_text() != text
    ]
    assert not stale, f"docs out of date, run `mrcomm docs`: {stale}"


def test_every_argument_and_metric_is_documented():
    from mrcomm_env.registry import env_class, env_ids

    for path, text in expected_docs(DOCS).items():
        if path.name == "index.md":
            assert all(env_id in text for env_id in env_ids())
            continue
        env_id = next(e for e in env_ids() if path.stem == e.split("/")[1])
        cls = env_class(env_id)
        assert all(f"`{arg}`" in text for arg in cls.PARAMS)
        assert all(f"`{m}`" in text for m in cls.METRICS)


def _site_nav_pages() -> set[str]:
    """Every page named in mkdocs.yml's nav (a plain-text read: the site's YAML tags need mkdocs to load)."""
    text = (ROOT / "mkdocs.yml").read_text()
    nav = text[text.index("\nnav:") :]
    return set(re.findall(r"([\w./-]+\.md)\s*$", nav, flags=re.MULTILINE))


def test_docs_site_shows_every_env_and_every_page():
    """The site (make docs-site) lists each registered env's page and every hand-written page under docs/."""
    from mrcomm_env.registry import env_ids, short_name

    pages = _site_nav_pages()
    for env_id in env_ids():
        assert f"envs/{short_name(env_id)}.md" in pages, f"{env_id} is missing from mkdocs.yml's nav"
    for page in (ROOT / "docs").glob("*.md"):
        name = "environments.md" if page.name == "index.md" else page.name  # docs/hooks.py renames the listing
        assert name in pages, f"docs/{page.name} is not in mkdocs.yml's nav"
    assert {"index.md", "reproductions/REPORT.md", "api.md"} <= pages


def test_changelog_holds_every_env_version_history():
    from mrcomm_env.registry import env_class, env_ids

    text = " ".join((ROOT / "CHANGELOG.md").read_text().split())
    for env_id in env_ids():
        section = text[text.index(f"### `{env_id}`") :]
        for version, change in env_class(env_id).VERSION_HISTORY:
            assert f"**{version}**: {' '.join(change.split())}" in section, f"{env_id} {version} is not in CHANGELOG.md"


def test_citation_names_every_env_paper():
    from mrcomm_env.registry import entry, env_ids

    citation = " ".join((ROOT / "CITATION.cff").read_text().split())
    for env_id in env_ids():
        title = entry(env_id).paper.split("*")[1]
        assert f'title: "{title}"' in citation and f'notes: "{env_id}"' in citation, env_id


def _gif_frames(path: Path) -> int:
    with Image.open(path) as image:
        assert image.format == "GIF", path
        return image.n_frames


def test_every_env_page_and_the_readme_show_a_recording_of_the_papers_algorithm():
    from mrcomm_env.experiments.docs import MEDIA_LIMIT_BYTES, MEDIA_STEPS, media_path
    from mrcomm_env.registry import env_ids, short_name

    readme = (ROOT / "README.md").read_text()
    for env_id in env_ids():
        gif = media_path(DOCS, env_id)
        page = (DOCS / "envs" / f"{short_name(env_id)}.md").read_text()
        assert f"(media/{gif.name})" in page and f"(docs/envs/media/{gif.name})" in readme, env_id
        assert gif.stat().st_size < MEDIA_LIMIT_BYTES, f"{gif} is {gif.stat().st_size:,} bytes"
        assert _gif_frames(gif) == MEDIA_STEPS + 1  # the reset frame, then one per step


def test_learning_page_shows_each_shipped_model_beside_the_papers_algorithm():
    from mrcomm_env.experiments.docs import MEDIA_LIMIT_BYTES, learned_media_path
    from mrcomm_env.registry import env_ids, short_name

    page = (DOCS / "learning.md").read_text()
    for env_id in env_ids():
        if not (ROOT / "agents" / "pretrained" / short_name(env_id) / "model.zip").exists():
            continue
        gif = learned_media_path(DOCS, env_id)
        assert f"(learning/{gif.name})" in page, env_id
        assert gif.stat().st_size < MEDIA_LIMIT_BYTES and _gif_frames(gif) > 1, gif
        with Image.open(gif) as image:
            assert image.size[0] == 2 * 400, "two panels side by side"
