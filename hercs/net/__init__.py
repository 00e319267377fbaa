"""Zenoh and the process around it: sessions, publishers, queries with their timeouts and
rediscovery, mutual TLS and peer authentication, back-off, stop signals, and the shell every
service process runs in."""
