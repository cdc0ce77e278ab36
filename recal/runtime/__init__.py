"""Process-level concerns of the numerics, kept apart from them: the C allocator's tuning and
running independent batches in forked worker processes. No numerics here, and nothing in
here decides a result: a batch gives the same answer in a worker as in the caller."""
