"""Run services: a request (what a user asks for), the run it starts (results folder, executor,
finish), resume, the dry run, suites and the paper page's standing."""
