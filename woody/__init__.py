"""woody: STEP tube extraction and cylinder-following reconstruction of woody structure."""
