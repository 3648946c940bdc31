"""The wording of scenario errors: a pydantic validation error as one line naming the field
(``gains.k_c: expected 6 entries, got 5``), with the closest valid key for a misspelt one."""

from __future__ import annotations

import difflib

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

_UNION_TAGS = {"float", "int", "str", "bool", "list", "dict", "none"}
"""Parts of a pydantic error location that name a branch of a union, not a key."""

_TYPE_ERRORS = {"float_type", "int_type", "list_type", "dict_type", "model_type", "string_type", "bool_type",
                "model_attributes_type", "int_from_float"}  # fmt: skip


def _where(loc: tuple) -> str:
    """``gains.k_e[2]``: keys joined by dots, list indices in brackets, union branches dropped."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not (any(c in part for c in "-[]") or part in _UNION_TAGS):
            out += f".{part}" if out else part
    return out or "scenario"


def _describe(value) -> str:
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return repr(value)


def _keys_at(loc: tuple, root: type[BaseModel]) -> list[str]:
    """The keys ``root`` allows at ``loc`` (a table's location), by walking the models."""
    model: type[BaseModel] | None = root
    for part in loc:
        if model is None or not isinstance(part, str) or part not in model.model_fields:
            continue  # list indices and union branches
        model = next((a for a in _types(model.model_fields[part].annotation) if _is_model(a)), None)
    return list(model.model_fields) if model is not None else []


def _types(annotation) -> list:
    args = getattr(annotation, "__args__", None)
    if not args:
        return [annotation]
    return [t for a in args for t in _types(a)]


def _is_model(t) -> bool:
    return isinstance(t, type) and issubclass(t, BaseModel)


def _unknown_key(loc: tuple, value, root: type[BaseModel], sections: bool) -> str:
    key, parent = loc[-1], loc[:-1]
    known = _keys_at(parent, root)
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    what = "section" if not parent and sections and isinstance(value, dict) else "key"
    hint = f" (did you mean {close[0]!r}?)" if close else f" (expected one of: {', '.join(known)})"
    return f"{_where(loc)}: unknown {what} {key!r}{hint}"


def _message(error: ErrorDetails, root: type[BaseModel], sections: bool) -> str:
    """One error in our words."""
    kind, ctx, value = error["type"], error.get("ctx", {}), error.get("input")
    if kind == "extra_forbidden":
        return _unknown_key(error["loc"], value, root, sections)
    where = _where(error["loc"])
    bounds = {"greater_than": ("> ", "gt"), "greater_than_equal": (">= ", "ge"), "less_than": ("< ", "lt"),
              "less_than_equal": ("<= ", "le")}  # fmt: skip
    if kind in bounds:
        op, key = bounds[kind]
        return f"{where}: must be {op}{ctx[key]:g}, got {value!r}"
    if kind == "finite_number":
        return f"{where}: must be a finite number, got {value!r}"
    if kind == "missing":
        return f"{where}: required key missing"
    if kind in ("too_short", "too_long"):
        size = ctx.get("min_length") if kind == "too_short" else ctx.get("max_length")
        return f"{where}: expected {'at least' if kind == 'too_short' else 'at most'} {size} entries, got {len(value)}"
    if kind == "literal_error":
        return f"{where}: expected {ctx['expected']}, got {_describe(value)}"
    if kind in _TYPE_ERRORS:
        expected = {"float_type": "a number", "int_type": "an integer", "int_from_float": "an integer",
                    "list_type": "a list", "string_type": "a string", "bool_type": "true or false"}  # fmt: skip
        return f"{where}: expected {expected.get(kind, 'a table')}, got {_describe(value)}"
    return f"{where}: {error['msg'].removeprefix('Value error, ')}"


def one_line(error: ValidationError, root: type[BaseModel], *, sections: bool = False) -> str:
    """The most useful error of validating ``root``, in our words: an unknown key first (a typo
    in a required key is also reported missing); of the branches of a union (a number or a
    list), the one the value's type selects. ``sections``: the root's tables are the file's
    sections (an unknown one is called a section)."""
    errors = error.errors()
    unknown = [e for e in errors if e["type"] == "extra_forbidden"]
    if unknown:
        return _message(unknown[0], root, sections)
    first = errors[0]
    field = _where(first["loc"])
    same = [e for e in errors if _where(e["loc"]).startswith(field)]
    if len(same) > 1:
        meaningful = [e for e in same if e["type"] not in _TYPE_ERRORS] or same
        deepest = max(len(e["loc"]) for e in meaningful)
        candidates = [e for e in meaningful if len(e["loc"]) == deepest]
        first = candidates[0]
        tied = [e for e in candidates if _where(e["loc"]) == _where(first["loc"])]
        if len(tied) > 1 and all(e["type"] in _TYPE_ERRORS for e in tied):
            return f"{field}: expected a number or a list of numbers, got {_describe(first['input'])}"
    return _message(first, root, sections)
