//! Photodiode sampling: ADC1 on PA1 (IN1), converting continuously at a fixed rate, DMA
//! into a raw circular buffer, decimated by 256 in a TIM5 interrupt (once per block) into a
//! bounded ring of 16-bit-effective samples, each stamped with the detector arm's step
//! count at the block's end, that `drain_samples` empties.
//!
//! The decimation and the ring, with the overrun rule (an ADC overrun, a DMA lap, a full
//! ring: each reported), are the library's ([`firmware::sampling`]); this module runs the
//! ADC, the DMA and the interrupt, and hands the library the DMA position, the ADC's
//! overrun flag, the DWT cycle count and the detector arm's step count (one atomic load,
//! [`crate::steppers::detector_steps`]).
//!
//! TIM5 IS LOCKED TO THE BLOCKS: its period is one block (98,304 cycles of the 96 MHz
//! clock that also makes ADCCLK, so they never drift apart) and it is started
//! [`PHASE_CYCLES`] after the conversions, so each interrupt comes just after a block
//! ended: it finds exactly that block and the step count it stamps is the count at the
//! block's end, to within the interrupt's latency (≲ 10 µs: a twentieth of a step at full
//! speed). A sweep's bins take their angles from these stamps. (A free-running 1 kHz
//! timer would stamp each block 0–1 ms late, sliding with the 24 µs difference: up to
//! 4.9 steps off at 60 °/s.)
//!
//! Rates: ADCCLK = PCLK2 96 MHz / 4 = 24 MHz ([`ADC_PRESCALER`], written at start); 84-cycle
//! sampling + 12-cycle conversion = 96 ADC clocks, so 250,000 conversions/s, one every 384
//! CPU cycles, paced by the crystal. 256 summed conversions (20 bits) shifted right by 4
//! make one sample of full scale 65,520 counts (`InstrumentConfig` full scale is 65,535)
//! every 1.024 ms ([`BLOCK_US`], announced in the handshake), 976.5625 samples/s. 256× oversampling gains 4 bits of resolution when
//! the input noise dithers the ADC by about an LSB (a TIA output does); it also averages
//! down mains and switching ripple within each 1 ms.
//!
//! Nothing blocks. No DMA interrupt is used (embassy owns those vectors): TIM5 reads the
//! DMA position (NDTR), and the time since its last run tells one lap of the raw buffer
//! from two.
//!
//! ISR cost: 256 loads and adds per sample (9 instructions a conversion at opt-level "z",
//! ≈ 12 cycles: `llvm-objdump -d` of the release ELF, the loop in `TIM5`) plus short
//! critical sections: ≈ 3,150 cycles ≈ 33 µs per 1.024 ms, ≈ 3 % of the CPU, at P1: below
//! the step timers, which preempt it, above USB and the time driver.
//!
//! INTERRUPTS STAY ON WHILE IT SUMS. A critical section masks every interrupt, the step
//! timers' too, and a step interrupt must run within 12 µs of a 20 µs segment
//! (`firmware::stepgen`): the sum of a block, ≈ 3,150 cycles (33 µs), held the lock
//! (issue 26 item 3).
//! Now the decimator ([`DECIMATOR`], TIM5's alone) is copied out of its cell, sums with
//! interrupts on, and is copied back; only each finished sample (or loss) goes into the
//! shared ring under the lock ([`SharedRing`]). The blocks it sums are whole blocks behind
//! the DMA's write position, which the DMA reaches again only three blocks (3 ms) later,
//! whatever preempts the sum meanwhile (the lap test reports a later service; the
//! library's model tests it with the sum slowed sixfold past its preemption). Interrupt-off
//! sections here now, by the same disassembly: the copy out and back, 3 instructions each;
//! a ring push, 26 instructions with the `RefCell` borrow, ≈ 50 cycles; a drain batch of
//! 16 samples ([`DetectorAdc::drain`], device task), 13 instructions a sample, ≈ 300
//! cycles (3 µs).
//!
//! RAM: the ring holds 256 samples and their stamps, 1.5 KiB (`firmware::sampling`).

use core::cell::{Cell, RefCell};
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicU16, Ordering};

use firmware::Sample;

use cortex_m::peripheral::DWT;
use defmt::warn;
use embassy_stm32::Peri;
use embassy_stm32::adc::Adc;
use embassy_stm32::gpio::Flex;
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::pac::adc::vals as adc_vals;
use embassy_stm32::pac::adccommon::vals as adc_common_vals;
use embassy_stm32::pac::dma::vals as dma_vals;
use embassy_stm32::peripherals::{ADC1, DMA2_CH0, PA1, TIM5};
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use firmware::sampling::{Decimator, OVERSAMPLE, RAW_LEN, SampleLoss, SampleRing, SampleSink};

/// ADCCLK's divider of PCLK2 (ADC_CCR.ADCPRE), written by [`DetectorAdc::start`]:
/// 96 MHz / 4 = 24 MHz, the fastest under the F411's 36 MHz. Everything below is counted
/// in it: a different divider (or PCLK2) changes the block length the handshake announces.
const ADC_PRESCALER: adc_common_vals::Adcpre = adc_common_vals::Adcpre::DIV4;
/// ADCCLK, Hz.
const ADC_CLOCK_HZ: u32 = crate::PCLK2_HZ / adcpre_divisor(ADC_PRESCALER);
/// Sampling time of the detector's channel (SMPR2), and its length in ADC clocks.
const SAMPLE_TIME: adc_vals::SampleTime = adc_vals::SampleTime::CYCLES84;
const SAMPLE_ADC_CLOCKS: u32 = 84;
/// ADC clocks of a 12-bit conversion after the sampling (RM0383 11.5: 12 for 12 bits).
const CONVERSION_ADC_CLOCKS: u32 = 12;
/// CPU cycles per conversion: 384 (96 ADC clocks of 4 CPU cycles).
const CYCLES_PER_CONVERSION: u32 =
    (SAMPLE_ADC_CLOCKS + CONVERSION_ADC_CLOCKS) * (crate::SYSCLK_HZ / ADC_CLOCK_HZ);
/// CPU cycles per block (one sample): 98,304.
const BLOCK_CYCLES: u32 = OVERSAMPLE as u32 * CYCLES_PER_CONVERSION;
// The derivation holds only if ADCCLK is a whole fraction of SYSCLK (TIM5 counts SYSCLK
// cycles for a block of ADC clocks: otherwise they drift apart) and within the datasheet's
// 36 MHz; the numbers the module doc and the handshake use are these.
const _: () = {
    assert!(crate::SYSCLK_HZ % ADC_CLOCK_HZ == 0);
    assert!(ADC_CLOCK_HZ <= 36_000_000);
    assert!(matches!(SAMPLE_TIME, adc_vals::SampleTime::CYCLES84) && SAMPLE_ADC_CLOCKS == 84);
    assert!(CYCLES_PER_CONVERSION == 384);
    assert!(BLOCK_CYCLES == 98_304);
};

/// The divider ADCPRE selects.
const fn adcpre_divisor(prescaler: adc_common_vals::Adcpre) -> u32 {
    match prescaler {
        adc_common_vals::Adcpre::DIV2 => 2,
        adc_common_vals::Adcpre::DIV4 => 4,
        adc_common_vals::Adcpre::DIV6 => 6,
        adc_common_vals::Adcpre::DIV8 => 8,
    }
}
/// The block period, µs: 1,024 (what the handshake announces as `detector_block_us`).
pub const BLOCK_US: u32 = BLOCK_CYCLES / (crate::SYSCLK_HZ / 1_000_000);
/// TIM5 starts this long after the conversions, so its interrupt follows each block's end
/// by this much: two conversions, for the last one's DMA transfer and margin.
const PHASE_CYCLES: u32 = 2 * CYCLES_PER_CONVERSION;
/// ADC1 channel of PA1.
const ADC_CHANNEL: u8 = 1;
/// DMA2 stream 0, channel 0 is ADC1.
const DMA_STREAM: usize = 0;

/// Written by the DMA, read by the TIM5 interrupt. Atomics, so that memory another bus
/// master writes is never assumed unchanged by the compiler.
static RAW: [AtomicU16; RAW_LEN] = [const { AtomicU16::new(0) }; RAW_LEN];

/// The decoded samples (TIM5 and the device task).
struct Sampling {
    ring: SampleRing,
}

/// The decimation's state: TIM5's alone after [`DetectorAdc::start`]. A `Cell` that TIM5
/// copies out, services and copies back (four words, a few cycles under the lock), so
/// that no lock is held while it sums.
static DECIMATOR: Mutex<CriticalSectionRawMutex, Cell<Decimator>> =
    Mutex::new(Cell::new(Decimator::new(CYCLES_PER_CONVERSION, 0)));

/// The ring behind its lock, as the decimation's sink: one short critical section per
/// sample or loss, after the sample is summed.
struct SharedRing;

impl SampleSink for SharedRing {
    fn push(&mut self, sample: u16, detector_steps: i32) {
        with_sampling(|sampling| sampling.ring.push(sample, detector_steps));
    }

    fn mark_loss(&mut self, loss: SampleLoss) {
        with_sampling(|sampling| sampling.ring.mark_loss(loss));
    }
}

/// Uninitialised until [`DetectorAdc::start`] writes it, so that it is in `.bss`: its
/// initial value is not all zeros (the ring's `None`s),
/// and as a constant initialiser it put 1,568 bytes in `.data`, whose image is in flash.
/// Reached only through [`with_sampling`].
static SAMPLING: Mutex<CriticalSectionRawMutex, RefCell<MaybeUninit<Sampling>>> =
    Mutex::new(RefCell::new(MaybeUninit::uninit()));

/// `f` on the sampling state, in a critical section.
///
/// Only for the TIM5 interrupt and the methods of a [`DetectorAdc`]: [`DetectorAdc::start`]
/// writes the state before it enables the interrupt and before it returns the
/// `DetectorAdc`, so neither can run before it is initialised.
fn with_sampling<R>(f: impl FnOnce(&mut Sampling) -> R) -> R {
    SAMPLING.lock(|sampling| {
        let mut sampling = sampling.borrow_mut();
        // SAFETY: initialised before any caller can exist (above).
        f(unsafe { sampling.assume_init_mut() })
    })
}

/// (Re)start the DMA stream from the start of `RAW`, then the conversions, then TIM5
/// [`PHASE_CYCLES`] later (from 0, so that its interrupts follow the blocks' ends); the
/// cycle count at which the conversions started.
fn start_conversions() -> u32 {
    let adc = pac::ADC1;
    let stream = pac::DMA2.st(DMA_STREAM);
    let tim = pac::TIM5;
    tim.cr1().modify(|w| w.set_cen(false));
    tim.cnt().write_value(0);
    tim.sr().modify(|w| w.set_uif(false));
    adc.cr2().modify(|w| w.set_dma(false));
    stream.cr().modify(|w| w.set_en(false));
    while stream.cr().read().en() {}
    // Clear the stream's flags (stream 0 is index 0 of LIFCR).
    pac::DMA2.ifcr(0).write(|w| {
        w.set_tcif(DMA_STREAM, true);
        w.set_htif(DMA_STREAM, true);
        w.set_teif(DMA_STREAM, true);
        w.set_dmeif(DMA_STREAM, true);
        w.set_feif(DMA_STREAM, true);
    });
    stream.par().write_value(adc.dr().as_ptr() as u32);
    stream.m0ar().write_value(RAW.as_ptr() as u32);
    stream.ndtr().write(|w| w.set_ndt(RAW_LEN as u16));
    stream
        .fcr()
        .write(|w| w.set_dmdis(dma_vals::Dmdis::ENABLED)); // direct mode
    // No interrupt enables: embassy's DMA2_STREAM0 handler stays idle.
    stream.cr().write(|w| {
        w.set_chsel(0);
        w.set_dir(dma_vals::Dir::PERIPHERAL_TO_MEMORY);
        w.set_psize(dma_vals::Size::BITS16);
        w.set_msize(dma_vals::Size::BITS16);
        w.set_minc(true);
        w.set_circ(true);
        w.set_pl(dma_vals::Pl::HIGH);
        w.set_en(true);
    });
    adc.sr().modify(|w| w.set_ovr(false));
    adc.cr2().modify(|w| w.set_dma(true));
    // Nothing may come between the start of the conversions and of TIM5.
    cortex_m::interrupt::free(|_| {
        adc.cr2().modify(|w| w.set_swstart(true));
        let started = DWT::cycle_count();
        while DWT::cycle_count().wrapping_sub(started) < PHASE_CYCLES {}
        tim.cr1().modify(|w| w.set_cen(true));
        started
    })
}

/// Once per block, just after it ended: turn every whole block of conversions the DMA has
/// written into one sample, stamped with the detector arm's step count.
#[interrupt]
fn TIM5() {
    let tim = pac::TIM5;
    if !tim.sr().read().uif() {
        return;
    }
    tim.sr().modify(|w| w.set_uif(false));
    // The clock first, then the DMA position: the lap test errs on the side of a loss.
    let now = DWT::cycle_count();
    let steps = crate::steppers::detector_steps();
    let overrun = pac::ADC1.sr().read().ovr();
    let remaining = usize::from(pac::DMA2.st(DMA_STREAM).ndtr().read().ndt());
    // Interrupts on from here to the copy back (see the module doc).
    let mut decimator = DECIMATOR.lock(Cell::get);
    let raw = |i: usize| RAW[i].load(Ordering::Relaxed);
    let restart = decimator.service(
        RAW_LEN - remaining,
        overrun,
        now,
        raw,
        steps,
        &mut SharedRing,
    );
    if restart {
        // The DMA missed a conversion and the ADC stopped (it should not: the DMA has
        // priority "high" and nothing else uses DMA2): restart from slot 0, TIM5 with it.
        decimator.restart(start_conversions());
    }
    DECIMATOR.lock(|cell| cell.set(decimator));
}

/// The running ADC path: owns ADC1, the DMA stream, TIM5 and PA1.
pub struct DetectorAdc {
    _adc: Adc<'static, ADC1>,
    _dma: Peri<'static, DMA2_CH0>,
    _timer: Timer<'static, TIM5>,
    _pin: Flex<'static>,
}

impl DetectorAdc {
    /// Configure and start sampling at once.
    pub fn start(
        adc: Peri<'static, ADC1>,
        dma: Peri<'static, DMA2_CH0>,
        tim5: Peri<'static, TIM5>,
        pin: Peri<'static, PA1>,
    ) -> DetectorAdc {
        let mut pin = Flex::new(pin);
        pin.set_as_analog();
        // Clock on, embassy's prescaler, ADON.
        let adc = Adc::new(adc);
        // DMA2 clock (embassy's init enables it already; harmless if so).
        pac::RCC.ahb1enr().modify(|w| w.set_dma2en(true));
        let regs = pac::ADC1;
        regs.cr2().modify(|w| w.set_adon(false));
        // Our prescaler, with the ADC off: embassy picks the fastest ADCCLK under 36 MHz from
        // PCLK2 (DIV4 today too), but BLOCK_CYCLES and the block the handshake announces are
        // counted in ADC_PRESCALER, so it is written here, not assumed.
        pac::ADC1_COMMON
            .ccr()
            .modify(|w| w.set_adcpre(ADC_PRESCALER));
        regs.smpr2()
            .modify(|w| w.set_smp(usize::from(ADC_CHANNEL), SAMPLE_TIME));
        regs.sqr1().modify(|w| w.set_l(0)); // one conversion per sequence
        regs.sqr3().modify(|w| w.set_sq(0, ADC_CHANNEL));
        regs.cr1().modify(|w| {
            w.set_scan(false);
            w.set_res(adc_vals::Res::BITS12);
        });
        regs.cr2().modify(|w| {
            w.set_cont(true);
            w.set_dds(adc_vals::Dds::CONTINUOUS);
            w.set_align(adc_vals::Align::RIGHT);
            w.set_exten(adc_vals::Exten::DISABLED);
            w.set_adon(true);
        });
        cortex_m::asm::delay(96 * 3); // tSTAB: 3 µs at 96 MHz

        // TIM5 (32 bits) counts its own clock (2 × PCLK1 = SYSCLK here) for one block.
        let timer = Timer::new(tim5);
        let timer_clocks = u64::from(BLOCK_CYCLES) * u64::from(timer.get_clock_frequency().0)
            / u64::from(crate::SYSCLK_HZ);
        // Exact: PSC 0, ARR 98,303.
        timer.set_period_clocks(timer_clocks, RoundTo::Slower);
        timer.generate_update_event();
        timer.enable_update_interrupt(true);
        interrupt::TIM5.unpend();
        // Below the step timers (they preempt the decimation), above USB and the time
        // driver: it has 2 ms before the DMA laps the raw buffer.
        interrupt::TIM5.set_priority(Priority::P1);
        // The sampling state, before anything can read it (`with_sampling`).
        SAMPLING.lock(|sampling| {
            sampling.borrow_mut().write(Sampling {
                ring: SampleRing::new(),
            });
        });
        // The conversions, and TIM5 locked to them; the decimator from their start, before
        // TIM5's interrupt is enabled (its first update is a block, 1 ms, away; one
        // pending by then would find the decimator set all the same).
        let started = start_conversions();
        DECIMATOR.lock(|cell| cell.set(Decimator::new(CYCLES_PER_CONVERSION, started)));
        // SAFETY: the TIM5 handler is defined above and shares state only through atomics
        // and critical-section mutexes.
        unsafe { interrupt::TIM5.enable() };
        DetectorAdc {
            _adc: adc,
            _dma: dma,
            _timer: timer,
            _pin: pin,
        }
    }

    /// Hand every sample decoded since the last call to `sink`, oldest first, in short
    /// batches so that interrupts are never masked for long; the loss since the last
    /// drain, if any.
    pub fn drain(&mut self, sink: &mut dyn FnMut(Sample)) -> Result<(), SampleLoss> {
        let mut loss = None;
        loop {
            let mut batch = [Sample {
                counts: 0,
                detector_steps: 0,
            }; 16];
            let n = with_sampling(|sampling| {
                loss = loss.or(sampling.ring.take_loss());
                sampling.ring.pop_into(&mut batch)
            });
            for &sample in &batch[..n] {
                sink(sample);
            }
            if n < batch.len() {
                break;
            }
        }
        match loss {
            Some(loss) => {
                warn!("detector: samples lost ({})", loss);
                Err(loss)
            }
            None => Ok(()),
        }
    }

    /// An overrun of the ADC path since the last call (drained or not).
    pub fn take_fault(&mut self) -> Option<SampleLoss> {
        with_sampling(|sampling| sampling.ring.take_fault())
    }

    /// Forget the samples taken so far (not an overrun: see `firmware::sampling`).
    pub fn clear(&mut self) {
        with_sampling(|sampling| sampling.ring.clear());
    }
}
