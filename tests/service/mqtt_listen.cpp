// cdro-mqtt-listen HOST PORT FILTER: prints every message as {"topic": ..., "payload": ...},
// one JSON line each, flushed, until killed. The pytest subscriber.
#include <cstdio>
#include <cstdlib>
#include <string>

#include <mosquitto.h>
#include <nlohmann/json.hpp>

int main(int argc, char **argv)
{
    if (argc != 4) {
        std::fprintf(stderr, "usage: cdro-mqtt-listen HOST PORT FILTER\n");
        return 2;
    }
    static std::string filter = argv[3];
    mosquitto_lib_init();
    struct mosquitto *mosq = mosquitto_new(nullptr, true, nullptr);
    mosquitto_connect_callback_set(mosq, [](struct mosquitto *m, void *, int rc) {
        if (rc == 0) {
            mosquitto_subscribe(m, nullptr, filter.c_str(), 1);
        }
    });
    mosquitto_subscribe_callback_set(mosq, [](struct mosquitto *, void *, int, int, const int *) {
        std::printf("{\"subscribed\": true}\n");
        std::fflush(stdout);
    });
    mosquitto_message_callback_set(mosq, [](struct mosquitto *, void *, const mosquitto_message *message) {
        nlohmann::json line;
        line["topic"] = message->topic;
        line["payload"] =
            std::string(static_cast<const char *>(message->payload), static_cast<size_t>(message->payloadlen));
        line["retained"] = message->retain;
        std::printf("%s\n", line.dump().c_str());
        std::fflush(stdout);
    });
    if (mosquitto_connect(mosq, argv[1], std::atoi(argv[2]), 30) != MOSQ_ERR_SUCCESS) {
        std::fprintf(stderr, "cdro-mqtt-listen: cannot connect\n");
        return 1;
    }
    return mosquitto_loop_forever(mosq, -1, 1) == MOSQ_ERR_SUCCESS ? 0 : 1;
}
