"""The committed docs are exactly what the generator makes from the live environments."""

from pathlib import Path

from mrcomm_env.experiments.docs import expected_docs

DOCS = Path(__file__).resolve().parent.parent / "docs"


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
