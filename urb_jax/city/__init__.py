"""The city: network files, routes and the immutable Scenario every layer reads."""
