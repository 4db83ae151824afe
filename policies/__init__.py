"""Communication policies: scripted and learned (imports neither openmulti_env nor mapping)."""
