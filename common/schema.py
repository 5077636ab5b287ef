"""The config models' common ground: the strict base model, constrained number types, and the
rendering of a pydantic ``ValidationError`` as one ``ConfigError`` line.

A model's validator raises ``_FieldError`` to name the precise field, what was expected and what
was found; ``config_error`` turns a ``ValidationError`` into ``ConfigError`` whose text is one
line: ``configs/vehicles/orel.yaml: thrusters[3].thrust_n: expected > 0, got 0.0``. Used by the
shell's YAML loader (``hil.config``) and by the plant's fault-command check (``plant.faults``).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.errors import ConfigError, Raw

Vec3 = tuple[float, float, float]
PosFloat = Annotated[float, Field(gt=0)]
NonNegFloat = Annotated[float, Field(ge=0)]
Fraction = Annotated[float, Field(ge=0, le=1)]
Forgetting = Annotated[float, Field(gt=0, lt=1)]
RUN_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,79}$"
MAX_DURATION_S = 7 * 86400.0


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)



class _FieldError(ValueError):
    """Raised inside validators to report a precise field path, expectation and value."""

    def __init__(self, field: str, expected: str, found: object) -> None:
        super().__init__(f"{field}|{expected}")
        self.field = field
        self.expected = expected
        self.found = found


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _num(x: object) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


_EXPECT = {
    "greater_than": lambda c: f"> {_num(c['gt'])}",
    "greater_than_equal": lambda c: f">= {_num(c['ge'])}",
    "less_than": lambda c: f"< {_num(c['lt'])}",
    "less_than_equal": lambda c: f"<= {_num(c['le'])}",
    "missing": lambda c: "this field (it is required)",
    "extra_forbidden": lambda c: "no such field (unknown key)",
    "float_parsing": lambda c: "a number",
    "float_type": lambda c: "a number",
    "finite_number": lambda c: "a finite number",
    "int_parsing": lambda c: "an integer",
    "int_type": lambda c: "an integer",
    "int_from_float": lambda c: "an integer",
    "string_type": lambda c: "a string",
    "bool_type": lambda c: "true or false",
    "bool_parsing": lambda c: "true or false",
    "literal_error": lambda c: f"one of {c['expected']}",
    "tuple_type": lambda c: "a list",
    "list_type": lambda c: "a list",
    "dict_type": lambda c: "a mapping",
    "model_type": lambda c: "a mapping",
    "too_short": lambda c: f"at least {c['min_length']} item(s)",
    "too_long": lambda c: f"at most {c['max_length']} item(s)",
    "string_too_short": lambda c: "a non-empty string",
    "string_pattern_mismatch": lambda c: (
        "letters, digits and . _ + - (at most 80, not starting with a sign or dot)"
        if c.get("pattern") == RUN_NAME_PATTERN else f"a string matching {c.get('pattern')}"),
}


def config_error(where: str, exc: ValidationError, prefix: str = "") -> ConfigError:
    err = exc.errors(include_url=False)[0]
    field = _loc(err["loc"])
    found = err.get("input")
    ctx = err.get("ctx") or {}
    inner = ctx.get("error")
    if isinstance(inner, _FieldError):
        field = ".".join(p for p in (field, inner.field) if p)
        expected, found = inner.expected, inner.found
    elif err["type"] in _EXPECT:
        expected = _EXPECT[err["type"]](ctx)
    elif err["type"] == "value_error" and inner is not None:
        expected = str(inner)
    else:
        expected = err["msg"][0].lower() + err["msg"][1:]
    if err["type"] == "missing":
        found = Raw("nothing")
    if prefix:
        field = f"{prefix}.{field}" if field else prefix
    if isinstance(found, dict) and err["type"] != "dict_type":
        found = "a mapping"
    return ConfigError(where, field, expected, found)

