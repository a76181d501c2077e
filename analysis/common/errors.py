"""Input errors that name where the bad value came from.

Every problem with a user's file or table is reported as one line that names the
source (file name or ``<table>``) and the field, so the command line can print it
without a traceback.
"""


class InputError(ValueError):
    """Bad user input: a malformed file, an unknown name or an impossible value.

    Parameters
    ----------
    message : str
        What is wrong, in one sentence.
    source : str, optional
        The file (or other origin) the value came from.
    field : str, optional
        Where in the source, e.g. ``"[structure].mass"`` or ``"element[1].laws[0].k3"``.
    """

    def __init__(self, message: str, source: str | None = None, field: str | None = None):
        self.message = message
        self.source = source
        self.field = field
        super().__init__(self.one_line())

    def one_line(self) -> str:
        where = ": ".join(part for part in (self.source, self.field) if part)
        return f"{where}: {self.message}" if where else self.message

    def located(self, source: str | None = None, field_prefix: str | None = None) -> "InputError":
        """The same error with the source filled in and/or the field prefixed."""
        field = self.field
        if field_prefix:
            field = f"{field_prefix}.{field}" if field else field_prefix
        return InputError(self.message, source or self.source, field)
