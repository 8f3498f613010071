"""The one reader and writer of a config entry {value, unit, source} (config_files)."""

from __future__ import annotations

import pytest

from pneumatic_env.config_files import ConfigError, check_entry, is_entry, make_entry


def test_make_entry_writes_what_check_entry_reads():
    entry = make_entry(0.02, "A/N", "tuned: grid search", uncertainty=0.001)
    assert entry == {
        "value": 0.02,
        "unit": "A/N",
        "source": "tuned: grid search",
        "uncertainty": 0.001,
    }
    assert is_entry(entry) and not is_entry({"unit": "A/N"})
    assert check_entry("f.yaml: entry 'kp'", entry, keys=(*entry,)) is entry


@pytest.mark.parametrize(
    ("entry", "needle"),
    [
        (0.02, "must be a mapping with keys value, unit, source; got 0.02"),
        ({"value": 1, "unit": "-", "source": "s", "colour": 1}, "unknown key 'colour'; allowed"),
        ({"value": 1, "unit": "-"}, "is missing 'source'"),
        ({"value": 1, "unit": " ", "source": "s"}, "'unit' must be a non-empty string"),
        ({"value": 1, "unit": "-", "source": 3}, "'source' must be a non-empty string"),
    ],
)
def test_check_entry_names_the_entry_and_what_is_allowed(entry, needle):
    with pytest.raises(ConfigError) as exc:
        check_entry("f.yaml: entry 'kp'", entry)
    assert str(exc.value).startswith("f.yaml: entry 'kp'")
    assert needle in str(exc.value)
