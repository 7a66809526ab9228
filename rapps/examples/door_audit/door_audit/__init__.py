"""Door audit: a RApp written from the docs (docs/sdk.md)."""
