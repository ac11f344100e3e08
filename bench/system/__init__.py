"""The whole-system benchmark (`gridfleet bench system`): throughput and stop latency."""
