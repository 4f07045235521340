"""The one wording of pydantic validation errors."""
import pytest
from pydantic import BaseModel, Field, ValidationError, field_validator

from workers.common.validation import describe_errors


class Inner(BaseModel):
    n: int = Field(gt=0)


class Params(BaseModel):
    inner: Inner
    name: str

    @field_validator("name")
    @classmethod
    def _not_x(cls, v: str) -> str:
        if v == "x":
            raise ValueError("x is taken")
        return v


def _error(data) -> ValidationError:
    with pytest.raises(ValidationError) as info:
        Params.model_validate(data)
    return info.value


def test_names_each_field_path_and_message():
    exc = _error({"inner": {"n": 0}, "name": "x"})
    assert describe_errors(exc) == "inner.n: Input should be greater than 0; name: Value error, x is taken"


def test_whole_object_errors_use_the_given_name_and_lists_are_accepted():
    exc = _error([1])
    assert describe_errors(exc, "viewpoint").startswith("viewpoint: Input should be a valid dictionary")
    assert describe_errors(exc.errors(), "viewpoint") == describe_errors(exc, "viewpoint")


def test_skip_loc_drops_the_request_part_unless_nothing_is_left():
    errors = [{"loc": ("body", "width"), "msg": "too big"}, {"loc": ("body",), "msg": "missing"}]
    assert describe_errors(errors, skip_loc=1) == "width: too big; body: missing"
