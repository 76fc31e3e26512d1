#!/usr/bin/python3
"""rospy listener for the simnode tests: decodes std_msgs/UInt8MultiArray
and prints one line per message, "msg <seq> <latency_ms> <data_len>",
where seq and the source stamp are the simnode header in data[0:16].
usage: listen.py NODE_NAME TOPIC"""
import struct
import sys
import time

import rospy
from std_msgs.msg import UInt8MultiArray


def main():
    name, topic = sys.argv[1], sys.argv[2]
    rospy.init_node(name, anonymous=False, disable_signals=True)

    def cb(msg):
        data = bytes(msg.data)
        seq, stamp = struct.unpack_from("<QQ", data) if len(data) >= 16 else (0, 0)
        latency_ms = (time.time_ns() - stamp) / 1e6 if stamp else -1.0
        sys.stdout.write("msg %d %.3f %d\n" % (seq, latency_ms, len(data)))
        sys.stdout.flush()

    rospy.Subscriber(topic, UInt8MultiArray, cb, queue_size=100, tcp_nodelay=True)
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    rospy.spin()


if __name__ == "__main__":
    main()
