//! gonio firmware for the STM32F411CEU6 "Black Pill": board glue only.
//!
//! Clocks, pins, USB CDC-ACM, the watchdog, defmt logging, the step timers (TIM2, TIM3)
//! and the detector ADC (ADC1 + DMA2, decimated in TIM5). Every decision is made by
//! the `firmware` library ([`firmware::Device`]): this crate moves bytes between the USB
//! serial port and the device, polls it, and logs what happened.
//!
//! Tasks:
//! - `usb_task`: runs the USB device stack (enumeration, control requests).
//! - `usb_rx_task`: CDC-ACM OUT packets → `RX` pipe; reports disconnects.
//! - `usb_tx_task`: `TX` pipe → CDC-ACM IN transfers (64-byte packets, ZLP when needed).
//! - `device_task` (the protocol/link task): `RX` bytes → `Device::receive`, a 1 kHz
//!   `Device::poll`, reply frames → `TX`; feeds the watchdog. It never waits on USB, so a
//!   host that stops reading cannot stall the fail-safe logic.
//!
//! Interrupt priorities (lower number first): TIM2/TIM3 step timers P0, TIM5 ADC
//! decimation P1 (once per 1.024 ms block, locked to the ADC), OTG_FS P2, TIM4 (the embassy time driver) P3; the tasks in thread mode.
//! Critical sections mask the step timers too, so none may be long: the longest is
//! ≲ 500 cycles (5 µs, under a step interrupt's 12 µs deadline), estimated from
//! `llvm-objdump -d` of the release ELF (the board README's table: the ADC sum and the
//! USB queues, 3,150 and 3,450 cycles before issue 26 item 3, now hold no lock).
//! Panics, processor faults and stack overflows take the safe stop of [`fault`].
#![no_std]
#![no_main]

mod clocks;
mod detector_adc;
mod driver;
mod fault;
mod hardware;
mod pins;
mod stack;
mod steppers;
mod timing;

use core::cell::RefCell;
use defmt::{error, info, warn};
use embassy_executor::Spawner;
use embassy_futures::select::{Either3, select3};

use defmt_rtt as _;
use embassy_stm32::gpio::{Level, Output};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::peripherals::{IWDG, USB_OTG_FS};
use embassy_stm32::time::Hertz;
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Config, bind_interrupts, pac};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Ticker};
use embassy_usb::class::cdc_acm::{CdcAcmClass, Receiver, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use firmware::Device;
use firmware::clock::ClockFault;
use firmware::config::InstrumentConfig;
use firmware::txqueue::{DropLog, FrameQueue};
use hardware::BoardHardware;
use protocol::{MAX_FRAME_LEN, PROTOCOL_VERSION, USB_PRODUCT, USB_VID_PID};
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<USB_OTG_FS>;
});

type UsbDriver = Driver<'static, USB_OTG_FS>;

/// What this image is, for `gonio flash` to check before it writes it: the firmware
/// version (the one `DeviceInfo` reports), the protocol version and the board. In a
/// section that `gonio-info.x` keeps out of flash and RAM (an INFO section of the ELF).
#[used]
#[unsafe(link_section = ".gonio.info")]
static GONIO_INFO: [u8; protocol::FIRMWARE_INFO_LEN] = protocol::FirmwareInfo::encode(
    firmware::FIRMWARE_VERSION,
    PROTOCOL_VERSION,
    protocol::F411_BOARD_NAME,
);

/// Full-speed bulk packet size of the CDC data endpoints.
const USB_PACKET: usize = 64;
/// How often the device is polled (the library asks for at least every millisecond).
const POLL_PERIOD: Duration = Duration::from_micros(1000);
/// Watchdog timeout: the device task feeds it every poll.
const WATCHDOG_TIMEOUT_US: u32 = 500_000;

/// SYSCLK, Hz (`clock_config`): the step timers' and the ADC's cycle counts depend on it.
pub(crate) const SYSCLK_HZ: u32 = 96_000_000;
/// PCLK2, Hz (`clock_config`: APB2 undivided): the ADC's clock is divided from it.
pub(crate) const PCLK2_HZ: u32 = SYSCLK_HZ;

// The channels between the tasks lock with `ThreadModeRawMutex`, which masks no interrupt:
// every task runs in thread mode on the one executor, so they never preempt each other,
// and no interrupt handler touches these (the mutex asserts it: a lock from an interrupt
// panics into the fault handler's safe stop). With `CriticalSectionRawMutex` each lock
// was a critical section as long as its copy, with the step timers masked: a 256-byte
// frame pushed or popped byte by byte, 10 instructions ≈ 13.5 cycles a byte by
// `llvm-objdump -d` of the release ELF, ≈ 3,450 cycles (36 µs) against the step
// interrupt's 12 µs deadline (issue 26 item 3); a 64-byte packet into `RX`, ≈ 60
// instructions and a copy, ≲ 200 cycles. Now none of them masks anything.

/// Bytes from the host, waiting for the device task.
static RX: Pipe<ThreadModeRawMutex, { 2 * USB_PACKET }> = Pipe::new();
/// Frames for the host, waiting for the USB IN endpoint: whole frames or none (the
/// library's drop policy, `firmware::txqueue`).
static TX: Mutex<ThreadModeRawMutex, RefCell<FrameQueue<{ 4 * MAX_FRAME_LEN }>>> =
    Mutex::new(RefCell::new(FrameQueue::new()));
/// Something was queued in `TX`.
static TX_QUEUED: Signal<ThreadModeRawMutex, ()> = Signal::new();
/// The USB link went down (unplug, bus reset).
static DISCONNECTED: Signal<ThreadModeRawMutex, ()> = Signal::new();

/// The build's crystal ([`clocks::PLL`]: 25 or 8 MHz) → PLL (VCO 192 MHz) → SYSCLK 96 MHz,
/// USB 48 MHz. Only once [`clocks::check_crystal`] has found that crystal.
fn clock_config() -> Config {
    use clocks::PLL;
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv,
        PllSource, Sysclk,
    };
    let mut config = hsi_config();
    config.rcc.hse = Some(Hse {
        freq: Hertz(PLL.hse_hz),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll_src = PllSource::HSE;
    // The register encodings of the settings `clocks` asserts at compile time (PLLP's
    // field is P / 2 - 1).
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::from_bits(PLL.m as u8),
        mul: PllMul::from_bits(PLL.n as u16),
        divp: Some(PllPDiv::from_bits((PLL.p / 2 - 1) as u8)),
        divq: Some(PllQDiv::from_bits(PLL.q as u8)),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV1; // 96 MHz
    config.rcc.apb1_pre = APBPrescaler::DIV2; // 48 MHz (APB1 max 50 MHz)
    config.rcc.apb2_pre = APBPrescaler::DIV1; // 96 MHz
    config
}

/// The reset clocks, HSI 16 MHz alone: what the board runs on when it refuses its crystal
/// (and the base of [`clock_config`]).
fn hsi_config() -> Config {
    let mut config = Config::default();
    // The DWT cycle counter is the step deadline's and the ADC decimation's clock, and it
    // counts only while the core's HCLK runs: in the executor's sleep (WFE between events)
    // HCLK stops unless DBGMCU_CR.DBG_SLEEP keeps it on, and the count falls behind the
    // timers. Embassy's default sets
    // it (and DBG_STOP, DBG_STANDBY, unused here); written out so that it cannot change
    // under us. It costs the sleep's power saving, which a mains-powered instrument does
    // not need.
    config.enable_debug_during_sleep = true;
    config
}

/// Stop the board's timers and the watchdog while a debugger halts the core (DBGMCU
/// APB1 freeze bits), before any of them runs.
///
/// A halt is what a breakpoint, an attach or Ctrl-C in `probe-rs run` (the bring-up path)
/// does. Left running, a step timer (TIM2 source arm, TIM3 detector arm) repeats its
/// preloaded segment, since its interrupt no longer preloads the next or stops it, and
/// drives its arm into the mechanical end at the segment's rate. Frozen too: TIM5, the ADC
/// decimation, whose blocks follow its count (the ADC and its DMA cannot be frozen and
/// run on: after a halt longer than the raw buffer's 4 ms the next interrupt reports a DMA
/// lap, `AdcOverrun`, and the device stops, which is right after such a gap); TIM4,
/// embassy's time driver, so that time pauses with the core instead of the device's own
/// timeouts seeing the halt at once on resume (and a halt past its 65 ms period would lose
/// whole periods anyway: it counts them in its interrupts); the IWDG, so a halt does not
/// end in a watchdog reset. The DWT cycle counter (the step deadline's clock) does not
/// count in a halt. Nothing else times anything (TIM1, kept for the lamp, and TIM9–11 are
/// unused).
fn freeze_timers_in_debug_halt() {
    pac::DBGMCU.apb1fzr().modify(|w| {
        w.set_tim2(true);
        w.set_tim3(true);
        w.set_tim4(true);
        w.set_tim5(true);
        w.set_iwdg(true);
    });
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // First: the record a fault handler left is read and cleared before anything can fault.
    let reset_cause = fault::reset_cause();
    let resets = fault::count_reset(reset_cause);
    // The crystal before anything depends on it: started with a timeout and measured
    // against HSI (`clocks`); embassy's setup would wait for a missing one forever.
    let crystal = clocks::check_crystal();
    if let Err(fault) = crystal.verdict {
        // Refused before embassy's setup, which would wait for HSE: on HSI, the pins by
        // hand, and no embassy at all (so that its setup keeps the one constant clock
        // configuration the compiler folds: a second one costs 1.2 KiB of flash).
        clocks::enable_gpio_clocks();
        // SAFETY: `embassy_stm32::init` never runs on this path (`refuse_clocks` does not
        // return), so nothing else holds a peripheral.
        let p = unsafe { embassy_stm32::Peripherals::steal() };
        let hsi_cycles_per_ms = firmware::clock::HSI_HZ / 1_000;
        refuse_clocks(
            fault,
            crystal.measured_hse_hz,
            pins::take_board_pins!(p),
            hsi_cycles_per_ms,
        );
    }
    let p = embassy_stm32::init(clock_config());
    freeze_timers_in_debug_halt();
    // The flash accelerator (ART): embassy's clock setup writes the wait states and leaves
    // prefetch and the instruction and data caches off; at 3 wait states they hide the
    // flash latency for loops and constants (the step and ADC interrupts run from flash).
    pac::FLASH.acr().modify(|w| {
        w.set_prften(true);
        w.set_icen(true);
        w.set_dcen(true);
    });
    // The cycle counter: the step timers' and the ADC decimation's clock.
    let mut core = cortex_m::Peripherals::take().expect("the core peripherals, once");
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();
    // Below the step timers (P0) and the ADC decimation (P1): USB, then the time driver.
    embassy_stm32::interrupt::OTG_FS.set_priority(Priority::P2);
    embassy_stm32::interrupt::TIM4.set_priority(Priority::P3);
    info!(
        "gonio board: firmware {}, protocol v{}, reset cause {}",
        firmware::FIRMWARE_VERSION,
        PROTOCOL_VERSION,
        reset_cause
    );
    // SYSCLK measured against the crystal, now that the PLL runs from it.
    let sysclk_hz = match clocks::measure_sysclk() {
        Ok(sysclk_hz) => sysclk_hz,
        // (The blink's timing assumes the SYSCLK that was just found wrong.)
        Err(fault) => refuse_clocks(
            fault,
            crystal.measured_hse_hz,
            pins::take_board_pins!(p),
            SYSCLK_HZ / 1_000,
        ),
    };
    let pins = pins::take_board_pins!(p).split();
    info!(
        "clocks: HSE {} Hz measured against HSI (this build: {} Hz crystal), SYSCLK {} Hz measured against HSE (expected {} Hz)",
        crystal.measured_hse_hz,
        clocks::PLL.hse_hz,
        sysclk_hz,
        SYSCLK_HZ
    );

    info!(
        "drivers: {} (fault line active {}, STEP high {} µs)",
        driver::DRIVER.name,
        if driver::DRIVER.fault_active_high {
            "high"
        } else {
            "low"
        },
        driver::DRIVER.step_pulse_ticks
    );

    let mut watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
    watchdog.unleash();

    static EP_OUT_BUFFER: StaticCell<[u8; 256]> = StaticCell::new();
    let mut usb_config = usb::Config::default();
    // Bus-powered board: no VBUS sensing (PA9 stays free for the driver UART).
    usb_config.vbus_detection = false;
    let driver = Driver::new_fs(
        p.USB_OTG_FS,
        Irqs,
        p.PA12,
        p.PA11,
        EP_OUT_BUFFER.init([0; 256]),
        usb_config,
    );

    // pid.codes' shared test id (protocol::USB_VID_PID): a production build needs its own.
    let (vid, pid) = USB_VID_PID;
    let mut config = embassy_usb::Config::new(vid, pid);
    config.manufacturer = Some("gonio");
    config.product = Some(USB_PRODUCT);
    // The chip's unique id, so several instruments on one host can be told apart.
    config.serial_number = Some(embassy_stm32::uid::uid_hex());
    config.max_power = 100;
    config.max_packet_size_0 = 64;

    static CONFIG_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static CDC_STATE: StaticCell<State> = StaticCell::new();
    let mut builder = Builder::new(
        driver,
        config,
        CONFIG_DESCRIPTOR.init([0; 256]),
        BOS_DESCRIPTOR.init([0; 256]),
        &mut [], // no MS OS descriptors
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(
        &mut builder,
        CDC_STATE.init(State::new()),
        USB_PACKET as u16,
    );
    let usb = builder.build();
    let (sender, receiver) = class.split();

    let motors = pins.motors;
    let steppers = steppers::Steppers::new(
        p.TIM2,
        p.TIM3,
        motors.step_i,
        motors.step_r,
        motors.dir,
        motors.en,
    );
    let adc = detector_adc::DetectorAdc::start(p.ADC1, p.DMA2_CH0, p.TIM5, pins.detector);
    let boot = hardware::Boot {
        clocks: firmware::MeasuredClocks {
            hse_expected_hz: clocks::PLL.hse_hz,
            hse_measured_hz: crystal.measured_hse_hz,
            sysclk_expected_hz: SYSCLK_HZ,
            sysclk_measured_hz: Some(sysclk_hz),
        },
        resets,
    };
    let hardware = BoardHardware::new(
        steppers,
        adc,
        [pins.home, pins.diag],
        pins.lamp,
        pins.range,
        boot,
    );
    // The same unique ID as the USB serial string: the host records it as the instrument.
    // The reference instrument with this board's own detector block (its ADC clock's 1.024 ms).
    let config = InstrumentConfig {
        detector_block_us: detector_adc::BLOCK_US,
        ..InstrumentConfig::REFERENCE
    };
    let device = Device::new(config, hardware, reset_cause)
        .with_serial_number(embassy_stm32::uid::uid_hex());

    // Each task is spawned once into a pool of one: these cannot fail.
    spawner.spawn(defmt::unwrap!(usb_task(usb)));
    spawner.spawn(defmt::unwrap!(usb_rx_task(receiver)));
    spawner.spawn(defmt::unwrap!(usb_tx_task(sender)));
    spawner.spawn(defmt::unwrap!(device_task(device, watchdog, pins.led)));
    core::future::pending::<()>().await;
}

/// The clocks were refused ([`firmware::clock::ClockFault`]): every pin to its safe idle
/// state (drivers off, lamp off; held, since this never returns), neither USB nor the step
/// timers nor the ADC started, the reason in the log, and the fault's code blinked on the
/// LED (active low), forever, timed by the core's cycles (`cycles_per_ms`). No watchdog
/// runs: a reset would only find the same crystal again. The log line repeats with each
/// code, for a probe attached later.
fn refuse_clocks(
    fault: ClockFault,
    measured_hse_hz: Option<u32>,
    pins: pins::BoardPins,
    cycles_per_ms: u32,
) -> ! {
    let mut pins = pins.split();
    let blinks = fault.blinks();
    let period_ms = firmware::clock::blink_period_ms(blinks);
    let mut elapsed_ms = 0u32;
    loop {
        if elapsed_ms % period_ms == 0 {
            error!(
                "clocks refused: {} (HSE measured {} Hz against HSI; this build needs a {} Hz crystal): no USB, no motion; LED blinks {} times",
                fault,
                measured_hse_hz,
                clocks::PLL.hse_hz,
                blinks
            );
        }
        pins.led
            .set_level(if firmware::clock::blink_led_on(blinks, elapsed_ms) {
                Level::Low
            } else {
                Level::High
            });
        cortex_m::asm::delay(10 * cycles_per_ms);
        // Wraps after 49 days: the pattern restarts, nothing else.
        elapsed_ms = elapsed_ms.wrapping_add(10);
    }
}

#[embassy_executor::task]
async fn usb_task(mut usb: UsbDevice<'static, UsbDriver>) -> ! {
    usb.run().await
}

#[embassy_executor::task]
async fn usb_rx_task(mut receiver: Receiver<'static, UsbDriver>) -> ! {
    let mut packet = [0u8; USB_PACKET];
    loop {
        receiver.wait_connection().await;
        info!("USB configured: serving the host");
        // Ends with EndpointError::Disabled when the link goes down.
        while let Ok(n) = receiver.read_packet(&mut packet).await {
            RX.write_all(&packet[..n]).await;
        }
        info!("USB disconnected");
        DISCONNECTED.signal(());
    }
}

#[embassy_executor::task]
async fn usb_tx_task(mut sender: Sender<'static, UsbDriver>) -> ! {
    let mut transfer = [0u8; MAX_FRAME_LEN];
    loop {
        sender.wait_connection().await;
        loop {
            let n = TX.lock(|queue| queue.borrow_mut().pop(&mut transfer));
            if n == 0 {
                TX_QUEUED.wait().await;
                continue;
            }
            if write_transfer(&mut sender, &transfer[..n]).await.is_err() {
                break; // disconnected: the device task clears what is left
            }
        }
    }
}

/// Send `bytes` as one USB IN transfer: 64-byte packets, closed by a zero-length packet
/// when the last one is full (otherwise the host keeps waiting for more of the transfer).
async fn write_transfer(
    sender: &mut Sender<'static, UsbDriver>,
    bytes: &[u8],
) -> Result<(), EndpointError> {
    let packet = usize::from(sender.max_packet_size());
    for range in firmware::txqueue::transfer_packets(bytes.len(), packet) {
        sender.write_packet(&bytes[range]).await?;
    }
    Ok(())
}

/// The protocol/link task: the firmware library's device, fed and polled.
#[embassy_executor::task]
async fn device_task(
    mut device: Device<BoardHardware>,
    mut watchdog: IndependentWatchdog<'static, IWDG>,
    mut led: Output<'static>,
) -> ! {
    let mut ticker = Ticker::every(POLL_PERIOD);
    let mut bytes = [0u8; USB_PACKET];
    let mut drop_log = DropLog::new();
    loop {
        match select3(RX.read(&mut bytes), ticker.next(), DISCONNECTED.wait()).await {
            Either3::First(n) => {
                let was_done = device.handshake_done();
                device.receive(&bytes[..n], now_us(), &mut queue_frame);
                if let Some(version) = device.take_refused_version() {
                    warn!(
                        "handshake refused: protocol version mismatch (host v{}, firmware v{})",
                        version, PROTOCOL_VERSION
                    );
                }
                if !was_done && device.handshake_done() {
                    info!("handshake done: host speaks protocol v{}", PROTOCOL_VERSION);
                }
            }
            Either3::Second(()) => device.poll(now_us(), &mut queue_frame),
            Either3::Third(()) => {
                device.disconnected();
                RX.clear();
                TX.lock(|queue| queue.borrow_mut().clear());
            }
        }
        // At most one line a second, however many frames a host that stopped reading costs:
        // a defmt log blocks with interrupts off while a probe reads it.
        drop_log.count(TX.lock(|queue| queue.borrow_mut().take_dropped()));
        if let Some(dropped) = drop_log.due(now_us()) {
            warn!("USB send queue full: {} frames dropped", dropped);
        }
        led.set_level(if device.handshake_done() {
            Level::Low
        } else {
            Level::High
        });
        watchdog.pet();
    }
}

/// Queue one whole frame for the host, or drop it whole when the queue is full (a host
/// that does not read must not stall the device; `firmware::txqueue`).
/// The queue counts what it drops; `device_task` logs the count ([`DropLog`]).
fn queue_frame(frame: &[u8]) {
    if TX.lock(|queue| queue.borrow_mut().push_frame(frame).is_ok()) {
        TX_QUEUED.signal(());
    }
}

fn now_us() -> u64 {
    Instant::now().as_micros()
}
