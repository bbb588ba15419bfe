"""Runtime support for the factory: where stage folders live (local disk or object store)."""
