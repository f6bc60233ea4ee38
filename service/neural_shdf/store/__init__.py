"""Where results are stored: the cache the service and batch workers share.

- ``keys``: every key a result is stored under, one function per kind of result;
- ``codec``: checksummed framing of entries and the array encoding of results;
- ``backends``: byte stores (local disk, Redis, Redis with the disk as its fallback);
- ``breaker``: the circuit breaker in front of Redis;
- ``leases``: locks across processes and replicas that lapse unless renewed;
- ``cache``: ``ResultCache`` (typed entries, in-memory LRUs, compute-once under a lease)
  and ``open_cache(CacheConfig)``.

Nothing here knows about HTTP: the service (``neural_shdf.api``) and ``neural_shdf.batch``
both build on it.
"""
