"""Captures: many photographs of one sample sphere (being assembled)."""
