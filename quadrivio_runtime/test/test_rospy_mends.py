"""rospy_mends: a stale publisher list queued after a newer one no longer wins."""

import threading

from rospy.impl.registration import RegManager

from quadrivio_runtime.ros import compat as ros_package  # installs the mend on import
from quadrivio_runtime.ros import rospy_mends


class Handler:
    done = False


def pending_uris(rm, topic):
    """What RegManager.run connects to: the newest update of the topic (it drops the rest)."""
    topic_, uris = rm.updates[-1]
    assert topic_ == topic
    return uris


def test_the_publisher_named_by_the_masters_callback_survives_the_stale_registration_answer():
    rm = RegManager(Handler())
    rm.publisher_update("/vehicle/setpoint/auto", ["http://vm:37003/"])  # publisherUpdate from the master
    rm.publisher_update("/vehicle/setpoint/auto", [])  # registerSubscriber's answer, computed earlier
    assert pending_uris(rm, "/vehicle/setpoint/auto") == ["http://vm:37003/"]
    rm.publisher_update("/other", ["http://a/"])
    rm.publisher_update("/vehicle/setpoint/auto", ["http://b/"])
    assert pending_uris(rm, "/vehicle/setpoint/auto") == ["http://b/", "http://vm:37003/"]


def test_unmended_rospy_loses_it(monkeypatch):
    """The race as rospy has it (what makes the test above able to fail)."""
    def original(self, resolved_name, uris):
        with self.cond:
            self.updates.append((resolved_name, uris))
            self.cond.notify_all()
    monkeypatch.setattr(RegManager, "publisher_update", original)
    rm = RegManager(Handler())
    rm.publisher_update("/t", ["http://vm:37003/"])
    rm.publisher_update("/t", [])
    assert pending_uris(rm, "/t") == []


def test_installed_once_and_thread_safe():
    assert ros_package.mend_publisher_updates is rospy_mends.mend_publisher_updates
    first = RegManager.publisher_update
    rospy_mends.mend_publisher_updates()
    assert RegManager.publisher_update is first and first.quadrivio_mended
    rm = RegManager(Handler())
    threads = [threading.Thread(target=lambda k=k: [rm.publisher_update("/t", [f"http://{k}-{i}/"])
                                                    for i in range(50)]) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(pending_uris(rm, "/t"))) == 200  # the newest carries every URI
