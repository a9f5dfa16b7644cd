"""The substitution parser of launch files (fiper_ros/launcher/substitutions.py): exact cases by hand, errors in
one line naming the problem, and properties (plain text is itself; a template written out and parsed again
evaluates to the same text; quoting keeps spaces and parentheses)."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fiper_ros.launcher.substitutions import (
    Context, Substitution, SubstitutionError, evaluate, has_substitution, parse, substitute,
)

SHARES = {"fiper_ros": "/opt/share/fiper_ros", "pkg-b": "/share/pkg-b"}


def share(name: str) -> str:
    if name not in SHARES:
        raise SubstitutionError(f"$(find-pkg-share {name}): no package {name!r}")
    return SHARES[name]


CONTEXT = Context(variables={"a": "1", "name": "calibration_dir", "calibration_dir": "/cal", "empty": ""},
                  env={"HOME": "/home/u", "WHICH": "name"}, package_share=share, dirname="/launch")


@pytest.mark.parametrize(("text", "expected"), [
    ("plain text", "plain text"),
    ("", ""),
    ("$(var a)", "1"),
    ("x$(var a)y", "x1y"),
    ("$(var a)$(var a)", "11"),
    ("$(find-pkg-share fiper_ros)/models/sorting", "/opt/share/fiper_ros/models/sorting"),
    ("$(find-pkg-share pkg-b)", "/share/pkg-b"),
    ("$(env HOME)/x", "/home/u/x"),
    ("$(env UNSET_HERE fallback)", "fallback"),
    ("$(env UNSET_HERE 'two words')", "two words"),
    ("$(env HOME 'ignored default')", "/home/u"),
    ("$(dirname)/params.yaml", "/launch/params.yaml"),
    ("$(var $(var name))", "/cal"),  # nested: the argument is itself substituted
    ("$(var $(env WHICH))", "calibration_dir"),
    ("$(var   a  )", "1"),  # spaces around the arguments
    ("cost: $5 (approx.)", "cost: $5 (approx.)"),  # a $ that opens no substitution is text
    ("$", "$"),
    ("$(env UNSET_HERE 'a)b')", "a)b"),  # a quoted ) does not close the substitution
    ('$(env UNSET_HERE "it\'s")', "it's"),
    ("$(env UNSET_HERE pre'$(var a)'post)", "pre1post"),  # a quoted piece inside an argument, substituted
    ("$(var empty)", ""),
])
def test_exact_cases(text: str, expected: str) -> None:
    assert substitute(text, CONTEXT) == expected


def test_the_parsed_form() -> None:
    assert parse("a$(var b)c") == ("a", Substitution("var", (("b",),)), "c")
    assert parse("$(env X 'd e')") == (Substitution("env", (("X",), ("d e",))),)
    assert parse("$(var $(var x))") == (Substitution("var", ((Substitution("var", (("x",),)),),)),)
    assert parse("$(dirname)") == (Substitution("dirname"),)
    assert not has_substitution("no $ here (really)") and has_substitution("a $(var b)")


@pytest.mark.parametrize(("text", "message"), [
    ("$(command ls)", "substitution $(command ...) is not supported by fiper launch (it reads $(var), $(env), "
                      "$(find-pkg-share), $(dirname), $(not), $(and), $(or))"),
    ("$(find-pkg-prefix fiper_ros)", "substitution $(find-pkg-prefix ...) is not supported"),
    ("x $(eval '1 + 2')", "substitution $(eval ...) is not supported"),
    ("$(var a", "unclosed $(var ..."),
    ("$(var", "unclosed $(var ..."),
    ("$(env X 'open)", "unclosed '"),
    ("$()", "a substitution without a name"),
    ("$(var)", "$(var) takes 1 argument(s), got 0"),
    ("$(var a b)", "$(var) takes 1 argument(s), got 2"),
    ("$(env)", "$(env) takes 1 to 2 argument(s), got 0"),
    ("$(dirname x)", "$(dirname) takes 0 argument(s), got 1"),
    ("$(var.x)", "expected a space or ')'"),
])
def test_malformed_or_unsupported_text_is_refused_in_one_line(text: str, message: str) -> None:
    with pytest.raises(SubstitutionError) as error:
        parse(text)
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize(("text", "message"), [
    ("$(var nope)", "$(var nope): no launch argument or let named 'nope'"),
    ("$(env UNSET_HERE)", "$(env UNSET_HERE): the environment variable is not set and no default is given"),
    ("$(find-pkg-share missing)", "$(find-pkg-share missing): no package 'missing'"),
])
def test_evaluation_errors_name_what_is_missing(text: str, message: str) -> None:
    with pytest.raises(SubstitutionError) as error:
        substitute(text, CONTEXT)
    assert message in str(error.value)


#: Text without ``$(``: plain fragments.
PLAIN = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=30).filter(lambda t: "$(" not in t
                                                                                           and not t.endswith("$"))
NAMES = st.sampled_from(sorted(CONTEXT.variables))


@given(PLAIN)
def test_text_without_a_substitution_is_itself(text: str) -> None:
    assert parse(text) in ((), (text,))
    assert substitute(text, CONTEXT) == text


@given(st.lists(st.one_of(PLAIN, NAMES.map(lambda n: ("var", n))), max_size=6))
def test_a_written_template_evaluates_to_its_pieces(pieces: list[str | tuple[str, str]]) -> None:
    text = "".join(p if isinstance(p, str) else f"$(var {p[1]})" for p in pieces)
    expected = "".join(p if isinstance(p, str) else CONTEXT.variables[p[1]] for p in pieces)
    assert evaluate(parse(text), CONTEXT) == expected


@given(st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="'$"), max_size=20))
def test_a_quoted_default_comes_back_as_written(default: str) -> None:
    assert substitute(f"$(env UNSET_HERE '{default}')", CONTEXT) == default
