"""`fiper demo`: the whole suite live on the shipped models (README command 1)."""
