"""The proof, apart from the tool: planted cases, blind diagnoses, scores. The tool never imports this package."""
