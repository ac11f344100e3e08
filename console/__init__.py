"""The operator's console: a client of the fleet's requests and views, and the commands built on
it (`gridfleet job`, `status`, `feed`, `clean`) and the fleet monitor the tests and benches use."""
