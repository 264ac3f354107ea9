"""Parameter values from the command line and params files, typed as the node's table says.

Why: rcl reads ``-p name:=value`` and ``--params-file`` with its own YAML rules, in which a plain
``y``, ``n``, ``yes``, ``on`` ... is a *boolean* (YAML 1.1), while PyYAML -- which writes the files
of ``ros2 param dump`` and of ``ros2 launch`` (``parameters=[{...}]``) -- writes the strings
``y`` and ``n`` unquoted. So ``channels: [x, y]`` as dumped by ``ros2 param dump`` fails to load
("Sequence should be of same type"), ``-p channel:=y`` gives ``True``, and ``-p rate:=2`` is an
integer for a double parameter. A ROS user expects the value to have the parameter's declared
type, as ``ros2 param set`` does (it parses with PyYAML and the node's type decides).

What: before ``rclpy.init``, :func:`normalize_ros_args` rewrites, for the parameters of the node's
``*_PARAMS`` table only:

* a **string** parameter given as a plain YAML scalar -> the same text as a quoted string
  (``channel:=y`` -> ``channel:="y"``); a **string_array** given as a sequence of plain scalars ->
  quoted elements (``[x, y]`` -> ``["x", "y"]``);
* a **double** (or each element of a **double_array**) given as a plain integer -> the same
  number with a decimal point (``rate:=2`` -> ``rate:=2.0``).

``-p``/``--param`` values are rewritten in place; a ``--params-file`` that needs a change is
copied to a temporary file with those scalars re-styled (every other byte of meaning unchanged:
the YAML node tree is re-emitted) and the copy is passed instead. Quoted values, other
parameters, other types and anything that is not a ros__parameters entry are left to rcl.

Pure Python (PyYAML); no rclpy.
"""
from __future__ import annotations

import os
import re
import tempfile
from typing import Any, Sequence

_INT = re.compile(r"^[-+]?(0|[1-9][0-9_]*)$")


def _param_types(specs: Sequence[Any]) -> dict[str, str]:
    return {s.name: s.type for s in specs}


def _fix_scalar(node: Any, ptype: str) -> bool:
    """Re-style one plain ScalarNode for a parameter (element) of type ``ptype``; True if
    changed."""
    import yaml

    if not isinstance(node, yaml.ScalarNode) or node.style not in (None, ""):
        return False
    if ptype == "string":
        node.style = '"'
        node.tag = "tag:yaml.org,2002:str"
        return True
    if ptype == "double" and _INT.match(node.value):
        node.value = node.value.replace("_", "") + ".0"
        node.tag = "tag:yaml.org,2002:float"
        return True
    return False


def _fix_value(node: Any, ptype: str) -> bool:
    import yaml

    if ptype in ("string", "double"):
        return _fix_scalar(node, ptype)
    if ptype in ("string_array", "double_array") and isinstance(node, yaml.SequenceNode):
        changed = False
        for item in node.value:
            changed |= _fix_scalar(item, ptype[: -len("_array")])
        if changed:
            node.flow_style = True
        return changed
    return False


def fix_value_text(text: str, ptype: str) -> str:
    """The text of one ``-p name:=TEXT`` value, re-styled for a parameter of type ``ptype``."""
    import yaml

    try:
        node = yaml.compose(text)
    except yaml.YAMLError:
        return text  # rcl reports it
    if node is None or not _fix_value(node, ptype):
        return text
    return yaml.serialize(node, width=1 << 30).strip().removesuffix("...").strip()


def fix_params_file(text: str, types: dict[str, str]) -> str | None:
    """The params file ``text`` with the plain values of the table's parameters re-styled, or
    None when nothing needs a change (or the text is not YAML: rcl reports that)."""
    import yaml

    try:
        root = yaml.compose(text)
    except yaml.YAMLError:
        return None
    if root is None:
        return None
    changed = False

    def walk(node: Any) -> None:
        nonlocal changed
        if not isinstance(node, yaml.MappingNode):
            return
        for key, value in node.value:
            if isinstance(key, yaml.ScalarNode) and key.value == "ros__parameters" and \
                    isinstance(value, yaml.MappingNode):
                for pkey, pvalue in value.value:
                    ptype = types.get(getattr(pkey, "value", None))
                    if ptype is not None:
                        changed |= _fix_value(pvalue, ptype)
            else:
                walk(value)

    walk(root)
    return yaml.serialize(root, width=1 << 30) if changed else None


def normalize_ros_args(argv: Sequence[str], specs: Sequence[Any]) -> tuple[list[str], list[str]]:
    """``argv`` with the node's parameter values re-styled (module docstring), and the temporary
    params files created (the caller removes them after ``rclpy.init``)."""
    types = _param_types(specs)
    out: list[str] = []
    temps: list[str] = []
    in_ros = False
    i = 0
    args = list(argv)
    while i < len(args):
        a = args[i]
        if a == "--ros-args":
            in_ros = True
        elif a == "--" and in_ros:
            in_ros = False
        elif in_ros and a in ("-p", "--param") and i + 1 < len(args):
            out += [a, _fix_param_rule(args[i + 1], types)]
            i += 2
            continue
        elif in_ros and a == "--params-file" and i + 1 < len(args):
            out += [a, _fix_file(args[i + 1], types, temps)]
            i += 2
            continue
        out.append(a)
        i += 1
    return out, temps


def _fix_param_rule(rule: str, types: dict[str, str]) -> str:
    name, sep, value = rule.partition(":=")
    if not sep:
        return rule
    ptype = types.get(name.rpartition(":")[2])  # "node:param" or "param"
    return rule if ptype is None else f"{name}:={fix_value_text(value, ptype)}"


def _fix_file(path: str, types: dict[str, str], temps: list[str]) -> str:
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError):
        return path  # rcl reports it
    fixed = fix_params_file(text, types)
    if fixed is None:
        return path
    fd, tmp = tempfile.mkstemp(prefix="flight_fdi_params_", suffix=".yaml")
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(fixed)
    temps.append(tmp)
    return tmp
