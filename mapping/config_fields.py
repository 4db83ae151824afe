"""Field metadata shared by the settings dataclasses (a leaf module: every config may import it)."""

NEUTRAL_DEFAULT = {"neutral_default": True}
"""Metadata of a setting added after runs were recorded whose default is the behaviour from before it
existed: ``mapping.pipeline.records.settings_record`` leaves it out at its default, so rows recorded
before it stay valid."""
