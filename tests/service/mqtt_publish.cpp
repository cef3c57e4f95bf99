// cdro-mqtt-publish HOST PORT TOPIC: publishes each line of stdin as one message (QoS 1, not
// retained), waiting for the broker's acknowledgement of each, then disconnects. The pytest
// stand-in for the robot's software publishing odometry.
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>

#include <mosquitto.h>

namespace {
int g_acknowledged = 0;
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        std::fprintf(stderr, "usage: cdro-mqtt-publish HOST PORT TOPIC < lines\n");
        return 2;
    }
    mosquitto_lib_init();
    struct mosquitto *mosq = mosquitto_new(nullptr, true, nullptr);
    mosquitto_publish_callback_set(mosq, [](struct mosquitto *, void *, int) { ++g_acknowledged; });
    if (mosquitto_connect(mosq, argv[1], std::atoi(argv[2]), 30) != MOSQ_ERR_SUCCESS) {
        std::fprintf(stderr, "cdro-mqtt-publish: cannot connect\n");
        return 1;
    }
    int sent = 0;
    std::string line;
    while (std::getline(std::cin, line)) {
        if (mosquitto_publish(mosq, nullptr, argv[3], static_cast<int>(line.size()), line.data(), 1, false) !=
            MOSQ_ERR_SUCCESS) {
            std::fprintf(stderr, "cdro-mqtt-publish: publish failed\n");
            return 1;
        }
        ++sent;
        // One at a time, so that the broker sees them in this order (a deadlock guard of
        // 3000 loops of at most 10 ms, not a speed assumption).
        for (int i = 0; i < 3000 && g_acknowledged < sent; ++i) {
            if (mosquitto_loop(mosq, 10, 1) != MOSQ_ERR_SUCCESS) {
                std::fprintf(stderr, "cdro-mqtt-publish: connection lost\n");
                return 1;
            }
        }
        if (g_acknowledged < sent) {
            std::fprintf(stderr, "cdro-mqtt-publish: no acknowledgement\n");
            return 1;
        }
    }
    mosquitto_disconnect(mosq);
    mosquitto_destroy(mosq);
    std::printf("%d\n", sent);
    return 0;
}
