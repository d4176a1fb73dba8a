"""A task's outputs: the result JSON (``--result-json``, latched on ``/baxter_pnp/result``), per-run files in the
output directory (``result.json``, ``final_view.png``, ``errors.png``; a multi-cycle run: ``cycle_NNN/`` and
``cycles.png``) and the plots. Results are dataclasses with ``to_json()`` (e.g. ``pick.PickResult``): ``success``,
``mode``, ``time_s`` (robot time, s), ``steps``, ``final_error_mm_est``, ``failure_reason``, ``history``
(``pick.StepRecord`` s: mm, deg, px).
"""
import json
import os

import numpy as np

RESULT_TOPIC = '/baxter_pnp/result'


class Outputs:
    """Where a run's results go: ``result_json`` (a path or None), ``output_dir`` (or None), and the latched
    ``/baxter_pnp/result`` topic (with ``publish``; needs ``rospy.init_node`` first)."""

    def __init__(self, output_dir=None, result_json=None, cycles_planned=1, mode='', publish=True):
        self.output_dir = output_dir
        self.result_json = result_json
        self.cycles_planned = cycles_planned
        self.mode = mode
        self._publisher = None
        if publish:
            import rospy
            from std_msgs.msg import String
            self._String = String
            self._publisher = rospy.Publisher(RESULT_TOPIC, String, queue_size=1, latch=True)

    @property
    def views_dir(self):
        """Where saved views go (``OUTPUT_DIR/views``), None without an output directory."""
        return None if not self.output_dir else os.path.join(self.output_dir, 'views')

    def cycle_done(self, results, annotated):
        """Publish and write the last of ``results`` (the cycles so far) with the last annotated view."""
        result = results[-1]
        if self._publisher is not None:
            self._publisher.publish(self._String(json.dumps(result.to_json())))
        if self.result_json:
            with open(self.result_json, 'w') as f:
                json.dump(results_json(results, self.cycles_planned, self.mode), f, indent=1)
        if self.output_dir and self.cycles_planned == 1:
            write_outputs(self.output_dir, result, annotated)
        elif self.output_dir:   # no plot per cycle: matplotlib's caches grow ~20 MiB over its first ~20 figures
            write_outputs(os.path.join(self.output_dir, 'cycle_%03d' % len(results)), result, annotated, plot=False)

    def run_done(self, results):
        """A multi-cycle run's summary plot ``cycles.png``."""
        if self.output_dir and self.cycles_planned > 1:
            plot_cycles(results, os.path.join(self.output_dir, 'cycles.png'))


def results_json(results, cycles_planned, mode):
    """The ``--result-json`` content: one run's result dict; with ``cycles_planned`` > 1 ``{"cycles": [result
    dicts of the finished cycles], "successes", "success" (all cycles so far succeeded), "mode",
    "cycles_planned"}``."""
    if cycles_planned == 1:
        return results[-1].to_json()
    successes = sum(r.success for r in results)
    return {'cycles': [r.to_json() for r in results], 'successes': successes,
            'success': successes == len(results) == cycles_planned, 'mode': mode,
            'cycles_planned': cycles_planned}


def write_outputs(output_dir, result, annotated, plot=True):
    """result.json, final_view.png (last annotated camera view) and, with ``plot``, errors.png (error vs step)."""
    import cv2
    os.makedirs(output_dir, exist_ok=True)
    with open(os.path.join(output_dir, 'result.json'), 'w') as f:
        json.dump(result.to_json(), f, indent=1)
    if annotated is not None:
        cv2.imwrite(os.path.join(output_dir, 'final_view.png'), annotated)
    if plot and result.history:
        plot_errors(result, os.path.join(output_dir, 'errors.png'))


def plot_errors(result, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    steps = [h.step for h in result.history]
    figure, (ax_mm, ax_px) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    ax_mm.plot(steps, [h.error_mm for h in result.history], 'o-', label='position error (mm)')
    ax_mm.plot(steps, [h.error_deg for h in result.history], 's--', label='orientation error (deg)')
    ax_mm.set_yscale('log')
    ax_mm.set_ylabel('estimated error to hover pose')
    ax_mm.legend()
    ax_mm.set_title('pick_square, mode %s: %s' % (result.mode, 'success' if result.success else result.failure_reason))
    ax_px.plot(steps, [h.error_px for h in result.history], 'o-', color='tab:green')
    ax_px.set_ylabel('image error (px)')
    ax_px.set_xlabel('step' if result.mode == 'pbvs' else 'iteration (camera frame)')
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def plot_cycles(results, path):
    """A multi-cycle run at a glance: each cycle's time to grasp (s) and final estimated error (mm), failed
    cycles marked with their reason."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    cycles = np.arange(1, len(results) + 1)
    colours = ['tab:green' if r.success else 'tab:red' for r in results]
    figure, (ax_time, ax_error) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax_time.bar(cycles, [r.time_s for r in results], color=colours)
    ax_time.set_ylabel('time to grasp (s)')
    ax_time.set_title('pick_square, mode %s: %d of %d cycles succeeded'
                      % (results[0].mode, sum(r.success for r in results), len(results)))
    for cycle, r in zip(cycles, results):
        if not r.success:
            ax_time.annotate(r.failure_reason, (cycle, 0), rotation=90, fontsize=7, va='bottom', ha='center')
    ax_error.plot(cycles, [np.nan if r.final_error_mm_est is None else r.final_error_mm_est for r in results], 'o')
    ax_error.set_ylabel('final estimated error (mm)')
    ax_error.set_xlabel('cycle')
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
