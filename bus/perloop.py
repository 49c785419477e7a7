"""Objects of which each asyncio event loop has exactly one, shared by the participants on it."""

from __future__ import annotations

import asyncio
import weakref
from typing import Any, ClassVar, TypeVar

Shared = TypeVar("Shared", bound="PerLoop")


class PerLoop:
    """Base of a class with one instance per event loop: :meth:`of` returns the loop's instance (made
    with its first user) and counts one more user; :meth:`release` counts one less and, after the
    last, forgets the instance (the next user of the loop gets a new one)."""

    _of_loop: ClassVar[weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, Any]]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._of_loop = weakref.WeakKeyDictionary()

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._users = 0

    @classmethod
    def of(cls: type[Shared], loop: asyncio.AbstractEventLoop) -> Shared:
        """The instance of ``loop``, counting one more user of it."""
        shared: Shared | None = cls._of_loop.get(loop)
        if shared is None:
            shared = cls._of_loop[loop] = cls(loop)
        shared._users += 1
        return shared

    @property
    def users(self) -> int:
        """How many users hold this instance now."""
        return self._users

    def release(self) -> bool:
        """One user is done with it; True when that was the last (the loop's instance is forgotten)."""
        self._users -= 1
        if self._users > 0:
            return False
        if self._of_loop.get(self._loop) is self:
            del self._of_loop[self._loop]
        return True
