"""What every stage relies on: the config's schema, atomic file writes, failure records, logging, the footprint."""
