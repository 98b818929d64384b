"""The one exception the add-on raises for the artist. No bpy here."""


class UserError(Exception):
    """Something the artist can fix; the message says what."""
