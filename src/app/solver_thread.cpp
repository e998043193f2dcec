#include "zsculpt/app/solver_thread.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "zsculpt/app/recording.h"
#include "zsculpt/core/errors.h"

namespace zsculpt::app {

namespace {
using Clock = std::chrono::steady_clock;
double seconds(Clock::duration d) {
  return std::chrono::duration<double>(d).count();
}
}  // namespace

SolverThread::SolverThread(std::unique_ptr<Session> session, const SolverThreadOptions& options,
                           std::shared_ptr<Recorder> recorder)
    : session_(std::move(session)), options_(options), recorder_(std::move(recorder)) {
  ZSCULPT_ASSERT(session_ != nullptr, "SolverThread needs a session");
  // Size every slot now so that publishing never allocates (vectors of pins and loads may
  // still grow when the user adds more of them).
  for (int i = 0; i < 3; ++i) session_->fill(buffer_.slot(i), Property::Stiffness);
  if (options_.startRunning) session_->apply(Play{});
}

SolverThread::~SolverThread() {
  stop();
}

void SolverThread::start() {
  if (started_) return;
  started_ = true;
  publish();
  thread_ = std::thread([this] { loop(); });
}

void SolverThread::stop() {
  {
    std::lock_guard lock(queueMutex_);
    stopRequested_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void SolverThread::push(Command command) {
  {
    std::lock_guard lock(queueMutex_);
    pending_.push_back(std::move(command));
  }
  wake_.notify_all();
}

void SolverThread::schedule(std::vector<ScheduledCommand> commands) {
  {
    std::lock_guard lock(queueMutex_);
    for (ScheduledCommand& c : commands) scheduled_.push_back(std::move(c));
    // Stable: commands for the same cycle keep their order.
    std::stable_sort(
        scheduled_.begin() + static_cast<std::ptrdiff_t>(nextScheduled_), scheduled_.end(),
        [](const ScheduledCommand& a, const ScheduledCommand& b) { return a.cycle < b.cycle; });
  }
  wake_.notify_all();
}

void SolverThread::setDisplayProperty(Property property) {
  displayProperty_.store(static_cast<int>(property), std::memory_order_relaxed);
  // Republish so a paused session shows the new property.
  runOnSolver([](Session&) { return std::string(); });
}

std::vector<std::string> SolverThread::takeMessages() {
  std::lock_guard lock(messageMutex_);
  std::vector<std::string> out;
  out.swap(messages_);
  return out;
}

void SolverThread::postMessage(std::string message) {
  if (message.empty()) return;
  std::lock_guard lock(messageMutex_);
  // Bounded: a flood of refused commands must not grow without end.
  if (messages_.size() >= 256) messages_.erase(messages_.begin());
  messages_.push_back(std::move(message));
}

void SolverThread::runOnSolver(std::function<std::string(Session&)> job) {
  {
    std::lock_guard lock(queueMutex_);
    jobs_.push_back(Job{pending_.size(), std::move(job)});
  }
  wake_.notify_all();
}

const Snapshot& SolverThread::latest() {
  buffer_.update();
  return buffer_.front();
}

Session& SolverThread::sessionWhenStopped() {
  ZSCULPT_ASSERT(!thread_.joinable(), "the session is the solver thread's while it runs");
  return *session_;
}

void SolverThread::publish() {
  Snapshot& s = buffer_.back();
  session_->fill(s, static_cast<Property>(displayProperty_.load(std::memory_order_relaxed)));
  s.serial = ++serial_;
  s.commandsApplied = applied_;
  s.solverSecondsPerStep = stepSecondsAverage_;
  s.simOverWall = simOverWall_;
  s.fallingBehind = fallingBehind_;
  buffer_.publish();
}

void SolverThread::applyPending() {
  {
    std::lock_guard lock(queueMutex_);
    draining_.clear();
    draining_.swap(pending_);
    runningJobs_.clear();
    runningJobs_.swap(jobs_);
  }
  auto applyOne = [this](const Command& command) {
    try {
      session_->apply(command);
      ++applied_;
      if (recorder_) recorder_->record(session_->cycle(), command);
    } catch (const std::exception& e) {
      ++applied_;  // counted as handled, so a script waiting for it does not hang
      postMessage(std::string(commandName(command)) + ": " + e.what());
    }
  };
  // Scripted commands due at this cycle come first: they were meant for it.
  for (;;) {
    Command next;
    {
      std::lock_guard lock(queueMutex_);
      if (nextScheduled_ >= scheduled_.size() ||
          scheduled_[nextScheduled_].cycle > session_->cycle())
        break;
      next = scheduled_[nextScheduled_++].command;
    }
    applyOne(next);
  }
  // The commands and the jobs in the order they were queued.
  size_t next = 0;
  for (Job& job : runningJobs_) {
    for (; next < job.after && next < draining_.size(); ++next) applyOne(draining_[next]);
    try {
      postMessage(job.run(*session_));
    } catch (const std::exception& e) {
      postMessage(e.what());
    }
  }
  for (; next < draining_.size(); ++next) applyOne(draining_[next]);
}

void SolverThread::loop() {
  Clock::time_point wallAnchor = Clock::now();
  double simAnchor = session_->simulation().time();
  bool wasRunning = false;
  // Simulated over wall time, measured over windows of at least half a second.
  Clock::time_point rateWall = wallAnchor;
  double rateSim = simAnchor;
  std::vector<std::string> notices;
  auto postNotices = [&] {
    session_->takeNotices(notices);
    for (std::string& n : notices) postMessage(std::move(n));
    notices.clear();
  };

  for (;;) {
    std::uint64_t appliedBefore = applied_;
    bool jobsRan = false;
    bool stopping = false;
    {
      std::lock_guard lock(queueMutex_);
      stopping = stopRequested_;
      jobsRan = !jobs_.empty();
    }
    // Everything pushed before stop() is applied (and recorded) before the thread ends.
    applyPending();
    bool changed = applied_ != appliedBefore || jobsRan;
    // What the commands had to say (an edit that lowered the time step) is said now, not at
    // the next cycle: a paused session may have none for a while.
    if (changed) postNotices();
    if (stopping) {
      if (changed) publish();
      break;
    }
    if (options_.maxCycles > 0 && session_->cycle() >= options_.maxCycles) {
      publish();
      break;
    }

    const Clock::time_point now = Clock::now();
    const double period = session_->simulation().period();
    bool step = false;
    Clock::time_point wakeAt = now + std::chrono::milliseconds(50);
    if (session_->running()) {
      session_->takeStepRequest();  // a single step while running means nothing
      if (!wasRunning) {
        wallAnchor = now;
        simAnchor = session_->simulation().time();
        rateWall = now;
        rateSim = simAnchor;
        wasRunning = true;
      }
      if (!options_.realTime) {
        step = true;
      } else {
        // Real time: the state at t + T is due once the wall clock reaches it.
        const double time = session_->simulation().time();
        if (time < simAnchor) {  // a reset moved time back: re-anchor
          simAnchor = time;
          wallAnchor = now;
        }
        const double due = simAnchor + seconds(now - wallAnchor) * options_.speed;
        if (time + period <= due) {
          step = true;
          // Cap the lag so a slow solver runs slower than real time instead of catching
          // up in bursts later.
          const double lag = due - (time + period);
          if (lag > kMaxLag * options_.speed) {
            simAnchor = time + period;
            wallAnchor = now;
          }
        } else {
          const double wait = (time + period - due) / options_.speed;
          wakeAt = now +
                   std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(wait));
        }
      }
    } else {
      wasRunning = false;
      step = session_->takeStepRequest();
    }

    if (step) {
      const Clock::time_point t0 = Clock::now();
      const Session::Outcome outcome = session_->advance();
      const double spent = seconds(Clock::now() - t0);
      stepSecondsAverage_ =
          stepSecondsAverage_ == 0.0 ? spent : 0.9 * stepSecondsAverage_ + 0.1 * spent;
      postNotices();
      if (outcome == Session::Outcome::Diverged) wasRunning = false;
      changed = true;
    }

    // Statistics shown by the UI: simulated over wall time, and whether the solver keeps
    // up (the paper's criterion: a step takes longer than the sampling time it simulates).
    const Clock::time_point after = Clock::now();
    if (session_->running()) {
      const double window = seconds(after - rateWall);
      if (window >= 0.5) {
        const double simulated = session_->simulation().time() - rateSim;
        simOverWall_ = simulated >= 0.0 ? simulated / window : simOverWall_;
        rateWall = after;
        rateSim = session_->simulation().time();
      }
      fallingBehind_ = options_.realTime && stepSecondsAverage_ * options_.speed > period;
    } else {
      simOverWall_ = 0.0;
      fallingBehind_ = false;
    }

    if (changed) publish();
    if (step) continue;

    // Nothing to do until the next step is due or a command arrives.
    std::unique_lock lock(queueMutex_);
    wake_.wait_until(lock, wakeAt, [this] {
      return stopRequested_ || !pending_.empty() || !jobs_.empty() ||
             (nextScheduled_ < scheduled_.size() &&
              scheduled_[nextScheduled_].cycle <= session_->cycle());
    });
  }
  finished_.store(true, std::memory_order_release);
}

}  // namespace zsculpt::app
