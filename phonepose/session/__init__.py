"""Reading and writing phonepose sessions (MCAP, protobuf)."""

from phonepose.session.reader import Message, SessionReader, SessionSummary
from phonepose.session.writer import SessionWriter

__all__ = ["Message", "SessionReader", "SessionSummary", "SessionWriter"]
