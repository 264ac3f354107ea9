"""The one parameter mechanism of all flight_fdi nodes.

Each node module declares its parameters in ONE place, a module-level tuple of :class:`ParamSpec`
named ``<SOMETHING>_PARAMS`` (e.g. ``FILTER_PARAMS``), next to ``NODE_NAME`` (the default node
name, e.g. ``"filter_node"``). Its documented params file is ``config/<NODE_NAME without a trailing
"_node">.yaml`` (``filter_node`` -> ``config/filter.yaml``, ``bag_player`` ->
``config/bag_player.yaml``); ``test/nodes/test_params.py`` checks every such pair generically, and
:func:`render_yaml` writes that file from the table.

API (stable; used by every node)::

    ParamSpec(name, type, default, description, unit="", min=None, max=None, step=None,
              min_exclusive=False, choices=None, non_empty=False, read_only=True)
        type: "double" | "int" | "bool" | "string" | "string_array" | "double_array" | "int_array"
        min/max/step: numeric range (inclusive; min_exclusive=True makes the lower bound strict);
                      applied to each element for numeric arrays
        choices:      allowed strings (for "string", or each element of "string_array")
        non_empty:    a string / array must not be empty
        read_only:    True (default) = a change needs a restart; False = may be set at run time
                      (validated by the same rules, then ``on_change`` is called)

    declare_parameters(node, specs, validator=None, on_change=None) -> dict[str, value]
        Declares each spec with a ParameterDescriptor (description, FloatingPointRange /
        IntegerRange, read_only, additional_constraints), reads the effective values (overrides
        from the command line / params file / ``parameter_overrides``), validates them and
        returns {name: python value}. ``validator(values)`` does cross-field checks and raises
        ParameterError (use :func:`fail`). Raises ParameterError (never rclpy's own exceptions).

    fail(name, value, allowed) -> NoReturn      raise ParameterError with the standard message
    spec_table(specs) -> dict[str, ParamSpec]   by name
    render_yaml(node_name, specs, header="") -> str   commented ROS params file
    render_module(module_name) -> str           the same for a node module (NODE_NAME, its table,
                                                optional PARAMS_FILE_HEADER); also from the shell:
        python -m flight_fdi.nodes.params flight_fdi.nodes.filter_node > config/filter.yaml
    format_yaml_value(value) -> str             a value as ROS's and PyYAML's parsers read it

A node's ``main()`` catches ParameterError, logs it as fatal and exits non-zero; constructing the
node in-process raises it.
"""
from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from typing import Any, Callable, Iterable, NoReturn, Sequence

from .errors import ParameterError

TYPES = ("double", "int", "bool", "string", "string_array", "double_array", "int_array")
_NUMERIC = ("double", "int", "double_array", "int_array")
_ARRAYS = ("string_array", "double_array", "int_array")


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: name, type, default, meaning, unit and what values are allowed."""

    name: str
    type: str
    default: Any
    description: str
    unit: str = ""
    min: float | None = None
    max: float | None = None
    step: float | None = None
    min_exclusive: bool = False
    choices: tuple[str, ...] | None = None
    non_empty: bool = False
    read_only: bool = True

    def __post_init__(self) -> None:
        if self.type not in TYPES:
            raise ValueError(f"ParamSpec {self.name}: type must be one of {TYPES}, "
                             f"got {self.type!r}")
        if self.choices is not None:
            object.__setattr__(self, "choices", tuple(self.choices))
        if self.type in _ARRAYS:
            object.__setattr__(self, "default", list(self.default))
            if not self.default:
                # rcl's params-file parser cannot type an empty sequence
                raise ValueError(f"ParamSpec {self.name}: an array default must not be empty")
        problem = check_value(self, self.default)
        if problem:
            raise ValueError(f"ParamSpec {self.name}: default {self.default!r} is invalid: "
                             f"{problem}")

    def allowed(self) -> str:
        """What values are allowed, in words (also the descriptor's additional_constraints)."""
        parts = []
        kind = {"double": "a number", "int": "an integer", "bool": "true or false",
                "string": "a string", "string_array": "a list of strings",
                "double_array": "a list of numbers", "int_array": "a list of integers"}[self.type]
        parts.append(kind)
        if self.type in _NUMERIC:
            each = " each" if self.type in _ARRAYS else ""
            if self.min is not None and self.max is not None:
                lo = "(" if self.min_exclusive else "["
                parts.append(f"{each} in {lo}{_num(self.min)}, {_num(self.max)}]".lstrip())
            elif self.min is not None:
                op = ">" if self.min_exclusive else ">="
                parts.append(f"{each} {op} {_num(self.min)}".lstrip())
            elif self.max is not None:
                parts.append(f"{each} <= {_num(self.max)}".lstrip())
            if self.step:
                parts.append(f"in steps of {_num(self.step)}")
        if self.choices is not None:
            if self.type == "string_array":
                parts.append("with elements from: " + ", ".join(self.choices))
            else:
                parts.append("one of: " + ", ".join(self.choices))
        if self.non_empty:
            parts.append("not empty")
        return ", ".join(parts)


def _num(v: float) -> str:
    return f"{v:g}"


def fail(name: str, value: Any, allowed: str) -> NoReturn:
    """Raise the standard ParameterError: names the parameter, the bad value and what is allowed."""
    raise ParameterError(f"invalid parameter '{name}': got {value!r}; allowed: {allowed}")


def spec_table(specs: Iterable[ParamSpec]) -> dict[str, ParamSpec]:
    table: dict[str, ParamSpec] = {}
    for s in specs:
        if s.name in table:
            raise ValueError(f"parameter {s.name} is specified twice")
        table[s.name] = s
    return table


def check_value(spec: ParamSpec, value: Any) -> str | None:
    """None when ``value`` is allowed by ``spec``, else a short reason."""
    t = spec.type
    scalar_ok = {
        "double": lambda v: isinstance(v, float),
        "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
        "bool": lambda v: isinstance(v, bool),
        "string": lambda v: isinstance(v, str),
    }
    if t in _ARRAYS:
        if not isinstance(value, (list, tuple)):
            return "wrong type"
        elems = list(value)
        etype = t[: -len("_array")]
        if not all(scalar_ok[etype](e) for e in elems):
            return "wrong type"
        if spec.non_empty and not elems:
            return "must not be empty"
        if etype == "string" and len(set(elems)) != len(elems):
            return "has duplicate elements"
    else:
        if not scalar_ok[t](value):
            return "wrong type"
        elems = [value]
        if spec.non_empty and value == "":
            return "must not be empty"
    for v in elems:
        if isinstance(v, float) and not math.isfinite(v):
            return "must be finite"
        if t in _NUMERIC:
            if spec.min is not None and (v < spec.min or (spec.min_exclusive and v == spec.min)):
                return "out of range"
            if spec.max is not None and v > spec.max:
                return "out of range"
            if spec.step and spec.min is not None:
                k = (v - spec.min) / spec.step
                if abs(k - round(k)) > 1e-9 * max(1.0, abs(k)):
                    return f"not a multiple of the step {_num(spec.step)} above {_num(spec.min)}"
        if spec.choices is not None and v not in spec.choices:
            return f"{v!r} is not one of {', '.join(spec.choices)}"
    return None


def _descriptor(spec: ParamSpec):
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    desc = ParameterDescriptor(
        name=spec.name,
        description=spec.description + (f" [{spec.unit}]" if spec.unit else ""),
        additional_constraints=spec.allowed(),
        read_only=spec.read_only,
    )
    if spec.type in ("double", "double_array") and (spec.min is not None or spec.max is not None):
        # rclpy checks a FloatingPointRange only for scalar doubles; arrays are checked below
        if spec.type == "double":
            desc.floating_point_range = [FloatingPointRange(
                from_value=-math.inf if spec.min is None else float(spec.min),
                to_value=math.inf if spec.max is None else float(spec.max),
                step=float(spec.step or 0.0))]
    if spec.type == "int" and (spec.min is not None or spec.max is not None):
        desc.integer_range = [IntegerRange(
            from_value=-(2**63) if spec.min is None else int(spec.min),
            to_value=2**63 - 1 if spec.max is None else int(spec.max),
            step=int(spec.step or 0))]
    return desc


def _override_value(node: Any, name: str, fallback: str) -> Any:
    # rclpy keeps the overrides privately; only used to name the bad value in the message.
    overrides = getattr(node, "_parameter_overrides", None) or {}
    p = overrides.get(name)
    return p.value if p is not None else fallback


def declare_parameters(node: Any, specs: Sequence[ParamSpec],
                       validator: Callable[[dict[str, Any]], None] | None = None,
                       on_change: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Declare, read and validate the parameters of ``node``; see the module docstring."""
    from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                                  ParameterException)

    table = spec_table(specs)
    values: dict[str, Any] = {}
    for spec in table.values():
        try:
            param = node.declare_parameter(spec.name, spec.default, _descriptor(spec))
        except InvalidParameterTypeException as exc:
            value = _override_value(node, spec.name, str(exc))
            hint = " (write a decimal point, e.g. 1.0)" if spec.type == "double" and \
                isinstance(value, int) and not isinstance(value, bool) else ""
            fail(spec.name, value, spec.allowed() + hint)
        except InvalidParameterValueException as exc:
            fail(spec.name, _override_value(node, spec.name, str(exc)), spec.allowed())
        except ParameterException as exc:
            raise ParameterError(f"invalid parameter '{spec.name}': {exc}") from None
        value = param.value
        if spec.type in _ARRAYS and value is not None:
            value = list(value)
        problem = check_value(spec, value)
        if problem:
            fail(spec.name, value, f"{spec.allowed()} ({problem})")
        values[spec.name] = value
    if validator is not None:
        validator(dict(values))
    warn_unknown(node)

    if any(not s.read_only for s in table.values()):
        _install_runtime_checks(node, table, values, validator, on_change)
    return values


def warn_unknown(node: Any) -> list[str]:
    """Warn about parameter overrides (command line, params file, ``parameter_overrides``) that
    name no declared parameter -- a misspelt name would otherwise be ignored without a word.
    Returns the unknown names."""
    import difflib

    overrides = getattr(node, "_parameter_overrides", None) or {}
    unknown = sorted(n for n in overrides if not node.has_parameter(n))
    declared = list(getattr(node, "_parameters", {}))
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        node.get_logger().warning(f"unknown parameter '{name}' ignored{hint}")
    return unknown


def _install_runtime_checks(node, table, values, validator, on_change) -> None:
    from rcl_interfaces.msg import SetParametersResult

    def check(params) -> SetParametersResult:
        proposed = dict(values)
        for p in params:
            if p.name not in table:
                continue
            v = list(p.value) if table[p.name].type in _ARRAYS else p.value
            problem = check_value(table[p.name], v)
            if problem:
                return SetParametersResult(
                    successful=False,
                    reason=f"invalid parameter '{p.name}': got {v!r}; allowed: "
                           f"{table[p.name].allowed()} ({problem})")
            proposed[p.name] = v
        if validator is not None:
            try:
                validator(dict(proposed))
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def apply(params) -> None:
        changed = False
        for p in params:
            if p.name in table:
                values[p.name] = list(p.value) if table[p.name].type in _ARRAYS else p.value
                changed = True
        if changed and on_change is not None:
            on_change(dict(values))

    node.add_on_set_parameters_callback(check)
    node.add_post_set_parameters_callback(apply)


# --- params-file rendering ---------------------------------------------------------------------

def format_yaml_value(value: Any) -> str:
    """A parameter value in YAML that both rcl's parser and PyYAML (YAML 1.1) type correctly:
    floats always carry a decimal point and a signed exponent (``1.0e-06``), strings are quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return ".nan"
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        text = repr(value)
        if "e" in text:
            mant, exp = text.split("e")
            if "." not in mant:
                mant += ".0"
            if exp[0] not in "+-":
                exp = "+" + exp
            text = f"{mant}e{exp}"
        elif "." not in text:
            text += ".0"
        return text
    if isinstance(value, str):
        import yaml  # PyYAML ships with the ROS wheels

        return yaml.safe_dump(value, default_style='"', allow_unicode=True,
                              width=math.inf).strip()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_yaml_value(v) for v in value) + "]"
    raise TypeError(f"cannot render {value!r} as a parameter value")


def render_yaml(node_name: str, specs: Sequence[ParamSpec], header: str = "") -> str:
    """A commented ROS 2 params file (``<node>: ros__parameters: ...``) with every parameter at
    its default, each preceded by a comment giving its meaning, unit and allowed values."""
    lines = [f"# {ln}".rstrip() for ln in header.strip().splitlines()] if header else []
    lines += [f"{node_name}:", "  ros__parameters:"]
    for s in specs:
        unit = f" [{s.unit}]" if s.unit else ""
        ro = "" if s.read_only else " Can be changed at run time."
        text = f"{s.description}{unit}. Allowed: {s.allowed()}.{ro}"
        lines += ["    # " + ln for ln in textwrap.wrap(text, width=94)]
        lines.append(f"    {s.name}: {format_yaml_value(s.default)}")
    return "\n".join(lines) + "\n"


def find_table(mod: Any) -> tuple:
    """The one ``*_PARAMS`` table of ParamSpec of a node module (ValueError when not exactly
    one)."""
    tables = [v for k, v in vars(mod).items() if k.endswith("_PARAMS") and isinstance(v, tuple)
              and v and all(isinstance(s, ParamSpec) for s in v)]
    if len(tables) != 1:
        raise ValueError(f"{mod.__name__}: expected one *_PARAMS table of ParamSpec, "
                         f"found {len(tables)}")
    return tables[0]


def render_module(module_name: str) -> str:
    """The params file of a node module (its NODE_NAME, its one ``*_PARAMS`` table and, when it
    has one, its ``PARAMS_FILE_HEADER`` comment)."""
    import importlib

    mod = importlib.import_module(module_name)
    try:
        table = find_table(mod)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    return render_yaml(mod.NODE_NAME, table, header=getattr(mod, "PARAMS_FILE_HEADER", ""))


if __name__ == "__main__":  # python -m flight_fdi.nodes.params flight_fdi.nodes.filter_node
    import sys

    if len(sys.argv) != 2:
        raise SystemExit("usage: python -m flight_fdi.nodes.params <node module>  "
                         "(writes its params file to stdout)")
    # run as __main__, this module is a second copy: use the package's ParamSpec class
    from flight_fdi.nodes.params import render_module as _render

    sys.stdout.write(_render(sys.argv[1]))
