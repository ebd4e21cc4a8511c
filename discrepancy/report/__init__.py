"""Report stage: JSON (schema-validated), Markdown with plots, rerun recordings of real/twin/corrected."""
