"""Alerts that reach a person: rules over what the fleet publishes, raised and cleared alerts,
a retained view, acknowledgements, a webhook and metrics (`gridfleet alerts`)."""
