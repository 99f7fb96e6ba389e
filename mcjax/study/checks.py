"""The spec reader's checks under their former name: everything here lives in
:mod:`mcjax.validation` (the one validation layer), re-exported for the callers that still
import it from here."""

from mcjax.validation import (BARE_KEY, SpecError, check_keys, check_text, count, is_int, is_number, key_text,  # noqa: F401
                              one_line, read_toml, set_value, show, subtable, suggest)
