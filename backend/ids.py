"""Row ids as the API takes them: positive and within the database's integer columns.

An id beyond the column's range cannot name a row; bounding it where it enters (path,
query or body) answers 422 naming the bound, where the database would fail on it.
"""

from typing import Annotated

import annotated_types

# The id columns are 32-bit integers on every database slidewatch runs on.
MAX_ROW_ID = 2**31 - 1

RowId = Annotated[int, annotated_types.Ge(1), annotated_types.Le(MAX_ROW_ID)]


def is_row_id(value: int) -> bool:
    """Whether `value` can be the id of a row at all."""
    return 1 <= value <= MAX_ROW_ID


def parse_row_id(text: str) -> int | None:
    """The row id written in `text`, or None when it is no id at all (not digits, or
    out of range: never converted when longer than any id)."""
    if not text.isascii() or not text.isdigit() or len(text) > len(str(MAX_ROW_ID)):
        return None
    value = int(text)
    return value if is_row_id(value) else None
