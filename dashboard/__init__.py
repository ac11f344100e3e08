"""The browser dashboard: a Flask app serving one page that speaks MQTT over websockets."""
