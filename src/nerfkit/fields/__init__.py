"""Neural fields: encodings and networks mapping coordinates to values."""
