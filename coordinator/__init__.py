"""The coordinator: world model, jobs, allocation, planning and the emergency stop."""
