"""The embedded MQTT broker (amqtt) that carries every gridfleet message by default."""

from gridfleet.broker.embedded import BrokerSettings, EmbeddedBroker

__all__ = ["BrokerSettings", "EmbeddedBroker"]
