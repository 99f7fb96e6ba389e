"""What a dataset says, with no JAX: statistics (t- and Wilson intervals, paired differences), the
schema's declarations read back, the tables, the consistency and error-floor sentences, and the
findings a report leads with."""
