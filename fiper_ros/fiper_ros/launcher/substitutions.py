"""The substitutions of a ROS 2 launch file (``$(var name)``, ``$(env NAME [default])``, ``$(find-pkg-share PKG)``,
``$(dirname)``, and the boolean ``$(not X)``, ``$(and X Y)``, ``$(or X Y)``), parsed and evaluated the way the
``launch`` package's front end does, without it.

A text is a *template*: plain fragments and substitutions, one after the other. A substitution is ``$(`` a name,
its arguments separated by spaces, and ``)``; an argument is itself a template (so ``$(var $(env WHICH))``
nests) and may be quoted with ``'`` or ``"`` to hold spaces or a ``)``. A ``$`` that does not open ``$(`` is
plain text. Only the substitutions above are known (:data:`SUPPORTED`); any other name is refused when the
text is parsed, with a one-line :class:`SubstitutionError` that names it, so a launch file using one fails at
once instead of half-starting. Pure: no rclpy, no ``launch``.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Union

from fiper_ros.launcher.errors import LaunchError

#: Substitution name -> (fewest, most) arguments.
SUPPORTED: dict[str, tuple[int, int]] = {"var": (1, 1), "env": (1, 2), "find-pkg-share": (1, 1), "dirname": (0, 0),
                                          "not": (1, 1), "and": (2, 2), "or": (2, 2)}
#: The texts a boolean substitution reads as true and as false (case folded), as ``launch`` does.
TRUE, FALSE = ("true", "1"), ("false", "0")
OPEN = "$("
QUOTES = "'\""


class SubstitutionError(LaunchError):
    """A launch-file text that cannot be parsed or evaluated (the message names the substitution and why)."""


@dataclass(frozen=True)
class Substitution:
    """``$(name args...)``; each argument is a :data:`Template`."""

    name: str
    args: tuple[Template, ...] = ()


Template = tuple[Union[str, Substitution], ...]
"""Plain fragments and substitutions, in order."""


@dataclass(frozen=True)
class Context:
    """What a substitution evaluates against.

    Attributes:
        variables: Launch configurations (declared arguments, ``let``), by name.
        env: The environment of ``$(env ...)``.
        package_share: Package name -> its installed share directory (raises :class:`SubstitutionError`).
        dirname: The directory of the launch file being read (``$(dirname)``).
    """

    variables: Mapping[str, str] = field(default_factory=dict)
    env: Mapping[str, str] = field(default_factory=dict)
    package_share: Callable[[str], str] = lambda name: _no_package(name)
    dirname: str = ""


def _no_package(name: str) -> str:
    raise SubstitutionError(f"$(find-pkg-share {name}): no package index to look {name!r} up in")


def parse(text: str) -> Template:
    """The template of ``text``; :class:`SubstitutionError` for an unclosed ``$(`` or an unsupported name."""
    template, end = _template(text, 0, stop="")
    assert end == len(text)
    return template


def evaluate(template: Template, context: Context) -> str:
    """The text ``template`` stands for in ``context``."""
    return "".join(part if isinstance(part, str) else _evaluate(part, context) for part in template)


def substitute(text: str, context: Context) -> str:
    """``text`` with its substitutions evaluated."""
    return evaluate(parse(text), context)


def has_substitution(text: str) -> bool:
    """Whether ``text`` holds a substitution (else it is taken literally)."""
    return any(isinstance(part, Substitution) for part in parse(text))


def _template(text: str, start: int, stop: str) -> tuple[Template, int]:
    """The template from ``start`` up to (not including) the first character of ``stop`` outside a substitution
    (``stop`` empty: to the end), and where it ended."""
    parts: list[str | Substitution] = []
    plain: list[str] = []
    i = start
    while i < len(text) and text[i] not in stop:
        if text.startswith(OPEN, i):
            if plain:
                parts.append("".join(plain))
                plain = []
            substitution, i = _substitution(text, i)
            parts.append(substitution)
        else:
            plain.append(text[i])
            i += 1
    if plain:
        parts.append("".join(plain))
    return tuple(parts), i


def _substitution(text: str, start: int) -> tuple[Substitution, int]:
    """The substitution opened at ``start`` (``$(``), and the index after its ``)``."""
    i = start + len(OPEN)
    name_start = i
    while i < len(text) and (text[i].isalnum() or text[i] in "-_"):
        i += 1
    name = text[name_start:i]
    if not name:
        raise SubstitutionError(f"a substitution without a name at character {start} of {text!r}")
    if name not in SUPPORTED:
        known = ", ".join(f"$({n})" for n in SUPPORTED)
        raise SubstitutionError(f"substitution $({name} ...) is not supported by fiper launch (it reads {known})")
    args: list[Template] = []
    while True:
        spaced = i
        while i < len(text) and text[i].isspace():
            i += 1
        if i >= len(text):
            raise SubstitutionError(f"unclosed $({name} ... in {text!r}")
        if text[i] == ")":
            break
        if i == spaced:
            raise SubstitutionError(f"$({name}: expected a space or ')' at character {i} of {text!r}")
        arg, i = _argument(text, i, name)
        args.append(arg)
    fewest, most = SUPPORTED[name]
    if not fewest <= len(args) <= most:
        wanted = str(fewest) if fewest == most else f"{fewest} to {most}"
        raise SubstitutionError(f"$({name}) takes {wanted} argument(s), got {len(args)} in {text!r}")
    return Substitution(name, tuple(args)), i + 1


def _argument(text: str, start: int, name: str) -> tuple[Template, int]:
    """One argument of ``$(name ...``: quoted pieces and unquoted ones up to a space or ``)``."""
    parts: list[str | Substitution] = []
    i = start
    while i < len(text) and not text[i].isspace() and text[i] != ")":
        if text[i] in QUOTES:
            quote = text[i]
            piece, end = _template(text, i + 1, stop=quote)
            if end >= len(text):
                raise SubstitutionError(f"$({name}: unclosed {quote} in {text!r}")
            i = end + 1
        else:
            piece, i = _template(text, i, stop=" \t\n)" + QUOTES)
        parts.extend(piece)
    return _joined(parts), i


def _joined(parts: list[str | Substitution]) -> Template:
    """``parts`` with neighbouring plain fragments joined."""
    out: list[str | Substitution] = []
    for part in parts:
        if isinstance(part, str) and out and isinstance(out[-1], str):
            out[-1] += part
        elif part != "":
            out.append(part)
    return tuple(out)


def _evaluate(substitution: Substitution, context: Context) -> str:
    args = [evaluate(arg, context) for arg in substitution.args]
    if substitution.name == "var":
        if args[0] not in context.variables:
            raise SubstitutionError(f"$(var {args[0]}): no launch argument or let named {args[0]!r}")
        return context.variables[args[0]]
    if substitution.name == "env":
        if args[0] in context.env:
            return context.env[args[0]]
        if len(args) == 2:
            return args[1]
        raise SubstitutionError(f"$(env {args[0]}): the environment variable is not set and no default is given")
    if substitution.name == "find-pkg-share":
        return context.package_share(args[0])
    if substitution.name in ("not", "and", "or"):
        values = [_boolean(substitution.name, arg) for arg in args]
        result = {"not": lambda: not values[0], "and": lambda: all(values), "or": lambda: any(values)}[substitution.name]()
        return "true" if result else "false"
    return context.dirname  # dirname


def _boolean(name: str, text: str) -> bool:
    """``text`` as a boolean argument of ``$(name ...)``; :class:`SubstitutionError` if it is none."""
    folded = text.strip().lower()
    if folded not in TRUE + FALSE:
        raise SubstitutionError(f"$({name} ...): {text!r} is not a boolean (true, false, 1 or 0)")
    return folded in TRUE
