"""protocol/toml_model.py: TOML text validated by a pydantic model; every error names the file, the
key path (``legs[1].length``) and why, in the words a user can act on. A small model of its own
here, so the contract is tested apart from the scene format."""

from __future__ import annotations

from typing import Annotated, Literal, Union

import pytest
from pydantic import BaseModel, ConfigDict, Field, model_validator

from hydrolink.protocol.toml_model import validate_toml


class SpecError(ValueError):
    """The error the caller supplies: records what validate_toml reports."""

    def __init__(self, source, key: str, why: str):
        self.source, self.key, self.why = str(source), key, why
        super().__init__(f"{source}: {key}: {why}")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Leg(_Strict):
    length: Annotated[float, Field(gt=0)]
    limit: float = 10.0

    @model_validator(mode="after")
    def _short(self) -> "Leg":
        if self.length > self.limit:
            raise ValueError(f"length: {self.length} is longer than limit = {self.limit}")   # relative key
        return self


class Cat(_Strict):
    type: Literal["cat"]
    lives: int = 9


class Dog(_Strict):
    type: Literal["dog"]
    good: bool = True


class Table(_Strict):
    title: str
    size: float = 1.0
    legs: list[Leg] = []
    pet: Annotated[Union[Cat, Dog], Field(discriminator="type")] | None = None

    @model_validator(mode="after")
    def _stable(self) -> "Table":
        if self.legs and len(self.legs) < 3:
            raise ValueError(f"legs[{len(self.legs) - 1}]: a table needs 3 legs to stand")  # absolute key
        return self


TAGS = ("cat", "dog")
LEGS = '[[legs]]\nlength = 1.0\n[[legs]]\nlength = 1.0\n[[legs]]\nlength = 1.0\n'


def error(text: str) -> SpecError:
    """The error validate_toml raises for ``text`` (file name t.toml)."""
    with pytest.raises(SpecError) as info:
        validate_toml(text, "t.toml", Table, SpecError, TAGS)
    assert info.value.source == "t.toml"
    return info.value


def test_valid_text_gives_the_model_with_its_defaults():
    t = validate_toml('title = "oak"\n' + LEGS + '[pet]\ntype = "dog"\n', "t.toml", Table, SpecError, TAGS)
    assert t.title == "oak" and t.size == 1.0 and [leg.length for leg in t.legs] == [1.0, 1.0, 1.0]
    assert isinstance(t.pet, Dog) and t.pet.good is True


def test_malformed_toml_names_the_file_and_the_parser_position():
    e = error('title = "oak"\nsize = \n')
    assert e.key == "" and e.why.startswith("not valid TOML:") and "line 2" in e.why


@pytest.mark.parametrize("text,key,why", [
    ('title = "oak"\nsize = "big"\n', "size", "(got 'big')"),                               # bad type
    ('title = "oak"\n[[legs]]\nlength = -1.0\n', "legs[0].length", "greater than 0"),        # bad value
    ('title = "oak"\ncolour = "red"\n', "colour", "unknown key"),                           # unknown key
    ('title = "oak"\n[[legs]]\nlength = 1.0\n[[legs]]\nlength = 1.0\nlenght = 1.0\n', "legs[1].lenght", "unknown key"),
    ('size = 2.0\n', "title", "required key is missing"),                                   # missing key
    ('title = "oak"\n[[legs]]\nlength = 1.0\n[[legs]]\nlimit = 1.0\n', "legs[1].length", "required key is missing"),
])
def test_field_errors_name_the_key_path(text, key, why):
    e = error(text)
    assert e.key == key, e
    assert why in e.why, e


def test_tagged_union_names_the_type_key_and_skips_the_branch_tag():
    e = error('title = "oak"\n[pet]\ntype = "fish"\n')
    assert e.key == "pet.type" and "must be one of" in e.why and "'cat'" in e.why and "(got 'fish')" in e.why
    e = error('title = "oak"\n[pet]\ntype = "cat"\nlives = "many"\n')
    assert e.key == "pet.lives", e                     # not pet.cat.lives: the tag is no key of the file


def test_validator_keys_relative_to_the_model_or_absolute():
    # a nested model's "length: why" is relative to where that model sits
    e = error('title = "oak"\n' + LEGS.replace("length = 1.0", "length = 12.0", 1))
    assert (e.key, e.why) == ("legs[0].length", "12.0 is longer than limit = 10.0")
    # the top model's "legs[1]: why" names a top-level key: it replaces the location
    e = error('title = "oak"\n[[legs]]\nlength = 1.0\n[[legs]]\nlength = 1.0\n')
    assert (e.key, e.why) == ("legs[1]", "a table needs 3 legs to stand")


def test_several_problems_are_each_listed_with_their_key():
    """The first problem names the key (the server's error field); every further one follows, one
    line each as "file: key: why" (issue 22: not "(and 2 more problem(s))")."""
    e = error('size = "big"\ncolour = 1\n')
    assert e.key == "title"
    assert e.why.splitlines() == ["required key is missing",
                                  "t.toml: size: Input should be a valid number, unable to parse string as a number "
                                  "(got 'big')",
                                  "t.toml: colour: unknown key"]
    assert "more problem" not in str(e)


@pytest.mark.parametrize("text,key,close", [
    ('titel = "oak"\n', "titel", "title"),                                              # top level
    ('title = "oak"\n[[legs]]\nlenght = 1.0\n', "legs[0].lenght", "length"),             # in a list of tables
    ('title = "oak"\n[pet]\ntype = "cat"\nlifes = 3\n', "pet.lifes", "lives"),           # in a union branch
    ('title = "oak"\n[pet]\ntype = "dog"\ngoood = true\n', "pet.goood", "good"),         # the other branch
])
def test_an_unknown_key_names_the_closest_valid_key(text, key, close):
    lines = str(error(text)).splitlines()
    assert f"t.toml: {key}: unknown key (did you mean {close!r}?)" in lines, lines


def test_an_unknown_key_far_from_every_valid_key_gets_no_guess():
    e = error('title = "oak"\nzzzzzz = 1\n')
    assert (e.key, e.why) == ("zzzzzz", "unknown key")


def test_every_problem_is_listed_up_to_the_cap():
    from hydrolink.protocol.toml_model import MAX_PROBLEMS
    legs = "".join(f"[[legs]]\nlength = {-i - 1}.0\n" for i in range(MAX_PROBLEMS + 5))
    lines = str(error('title = "oak"\n' + legs)).splitlines()
    assert len(lines) == MAX_PROBLEMS + 1 and lines[-1] == "t.toml: and 5 more problems"
    assert [ln.split(": ")[1] for ln in lines[:3]] == ["legs[0].length", "legs[1].length", "legs[2].length"]
