"""JSON Schemas of the project's outputs (package data).

``result-v1.schema.json``: the result of ``flight-fdi analyze --json``, ``run --json``,
``result.json`` and the smoother node; every result carries ``"schema": "flight-fdi/result/v1"``.
:func:`validate_result` checks a result against it (jsonschema).
"""
from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources

RESULT_SCHEMA = "result-v1.schema.json"


@lru_cache(maxsize=None)
def load(name: str = RESULT_SCHEMA) -> dict:
    """The schema document ``name`` of this package."""
    return json.loads(resources.files(__name__).joinpath(name).read_text(encoding="utf-8"))


def validate_result(result: dict) -> None:
    """jsonschema.ValidationError when ``result`` does not follow result-v1."""
    import jsonschema

    jsonschema.validate(result, load(RESULT_SCHEMA),
                        format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER)
