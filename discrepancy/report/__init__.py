"""Report stage: JSON (validated with ``jsonschema``), the plain-text summary, Markdown with plots, rerun
recordings of real/twin/corrected."""
